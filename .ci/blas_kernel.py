"""Print an OpenBLAS kernel (OPENBLAS_CORETYPE) this CPU runs other than the one OpenBLAS
picks by itself, for CI to repeat the floating-point-sensitive tests under; nothing if the
CPU runs no other (or NumPy's BLAS is not OpenBLAS)."""

import os
import subprocess
import sys

CANDIDATES = ("SkylakeX", "Haswell", "Zen", "Sandybridge")
PROBE = ("import numpy, threadpoolctl; print(next((i.get('architecture') for i in threadpoolctl.threadpool_info() "
         "if i['internal_api'] == 'openblas'), ''))")


def loaded_kernel(coretype: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    return subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def main() -> None:
    default = loaded_kernel(None)
    if not default:
        return
    for candidate in CANDIDATES:
        # A kernel the CPU lacks falls back to another: only one that loads as asked counts.
        if candidate != default and loaded_kernel(candidate) == candidate:
            print(candidate)
            return


if __name__ == "__main__":
    main()
