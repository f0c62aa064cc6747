"""Print the `env` arguments of CI's second pass: the same suite under another OpenBLAS
set-up than the machine's own. Where the machine presets OPENBLAS_CORETYPE (or
OPENBLAS_L2_SIZE), the second pass unsets both; where it does not, it sets a kernel this CPU
really loads (Haswell first, the set-up some machines of CI's kind preset) with a 512 KiB
L2. Prints nothing where NumPy's BLAS is not OpenBLAS or no other kernel loads; what the
second pass runs is said on stderr."""

import os
import subprocess
import sys

VARIABLES = ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")
CANDIDATES = ("Haswell", "Zen", "SkylakeX", "Sandybridge")
L2_SIZE = "512"
PROBE = ("import numpy, threadpoolctl; print(next((i.get('architecture') for i in threadpoolctl.threadpool_info() "
         "if i['internal_api'] == 'openblas'), ''))")


def loaded_kernel(settings: dict[str, str]) -> str:
    """The kernel OpenBLAS loads with these variables (none of the machine's own), or ""
    where it loads none (a kernel the CPU lacks kills the process: SIGILL)."""
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES} | settings
    run = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True)
    return run.stdout.strip() if run.returncode == 0 else ""


def main() -> None:
    preset = {k: os.environ[k] for k in VARIABLES if k in os.environ}
    if preset:
        kernel = loaded_kernel({})
        if kernel:
            print(" ".join(f"-u {k}" for k in VARIABLES))
            print(f"blas_kernel: the machine presets {preset}; second pass with both unset ({kernel})", file=sys.stderr)
        return
    if not loaded_kernel({}):
        print("blas_kernel: NumPy's BLAS is not OpenBLAS: no second pass", file=sys.stderr)
        return
    for candidate in CANDIDATES:
        settings = {"OPENBLAS_CORETYPE": candidate, "OPENBLAS_L2_SIZE": L2_SIZE}
        if loaded_kernel(settings) == candidate:  # a kernel the CPU lacks falls back or crashes
            print(" ".join(f"{k}={v}" for k, v in settings.items()))
            print(f"blas_kernel: second pass with {settings}", file=sys.stderr)
            return
    print("blas_kernel: this CPU loads none of the other kernels: no second pass", file=sys.stderr)


if __name__ == "__main__":
    main()
