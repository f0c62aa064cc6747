"""Without the gpu extra, qpik imports and the warp back-end and its device mirrors say
which extra to install."""

from __future__ import annotations


def test_without_warp_the_back_end_names_the_gpu_extra(run_without_modules):
    code = ("import qpik, mujoco\n"
            "from qpik.errors import MissingExtra\n"
            "for module in ('warp', 'warp_mirror'):\n"
            "    try:\n"
            "        __import__('qpik.batch.backends.' + module)\n"
            "        print(module, 'imported')\n"
            "    except MissingExtra as exc:\n"
            "        print(module, 'missing:', exc)\n")
    # the back-end needs both packages, the mirrors (Warp functions only) warp alone
    for hidden, mirror in ((("warp",), "missing:"), (("mujoco_warp",), "imported")):
        done = run_without_modules(code, hidden, timeout=120)
        assert done.returncode == 0, done.stderr
        backend_line, mirror_line = done.stdout.splitlines()
        assert backend_line.startswith("warp missing:") and '.[gpu]' in backend_line, done.stdout
        assert mirror_line.startswith(f"warp_mirror {mirror}"), done.stdout
        assert mirror == "imported" or '.[gpu]' in mirror_line, done.stdout
