"""Without the gpu extra, qpik imports and the warp back-end says which extra to install."""

from __future__ import annotations


def test_without_warp_the_back_end_names_the_gpu_extra(run_without_modules):
    code = ("import qpik, mujoco\n"
            "from qpik.errors import MissingExtra\n"
            "try:\n"
            "    from qpik.batch.backends.warp import WarpBackend\n"
            "except MissingExtra as exc:\n"
            "    print('missing:', exc)\n")
    for hidden in (("warp",), ("mujoco_warp",)):
        done = run_without_modules(code, hidden, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.startswith("missing:") and '.[gpu]' in done.stdout, done.stdout
