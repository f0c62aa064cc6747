"""The ``qpik`` command.

    qpik scenarios
    qpik run ROBOT --controller {qp,qp-hard,hqp,sns,pinv,jt,mink,placo} --scenario NAME [--solver S]
             [--mode {kinematic,physics}] [--out DIR] [--plot]
    qpik compare ROBOT --scenario NAME [--solvers daqp,osqp,...] [--mode M] [--out DIR] [--plot]

Bad input gives one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Callable, Sequence

from ..errors import QpikError
from ..rollout import MODES

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (and exit code 2)."""

    def error(self, message: str):
        raise _UsageError(f"{self.prog}: {message}")


class _UsageError(Exception):
    pass


def _solver_list(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of solver names")
    return names


def _plot(setup, logs, out_dir: Path, title: str) -> list[Path]:
    from .plotting import plot_level_errors, plot_logs  # matplotlib only when asked for

    return plot_logs(logs, setup.plot_joints, out_dir, title) + plot_level_errors(logs, out_dir, title)


def cmd_scenarios(args) -> int:
    from ..scenario import scenarios

    known = scenarios()
    width = max(len(n) for n in known)
    for info in known.values():
        print(f"{info.name.ljust(width)}  {info.robot:8s} {info.description}")
    return 0


def cmd_run(args) -> int:
    from .runs import format_table, run

    setup, log = run(args.robot, args.scenario, args.controller, args.solver, args.mode)
    out_dir = Path(args.out or f"out/run-{args.scenario}-{args.controller}-{args.mode}")
    summary = log.summary()
    print(format_table([summary]))
    log.save(out_dir)
    written = [out_dir / "summary.json", out_dir / "log.npz"]
    if args.plot:
        title = f"{setup.robot_name} / {args.scenario} / {args.controller} ({args.mode})"
        written += _plot(setup, [log], out_dir, title)
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def cmd_compare(args) -> int:
    from .runs import compare, format_table, write_compare

    setup, logs, notes = compare(args.robot, args.scenario, args.solvers, args.mode)
    summaries = [log.summary() for log in logs]
    print(f"{setup.robot_name} / {args.scenario} ({args.mode} mode)")
    print(format_table(summaries))
    for note in notes:
        print(note)
    out_dir = Path(args.out or f"out/compare-{args.scenario}-{args.mode}")
    written = [write_compare(out_dir, setup.robot_name, args.scenario, summaries, args.mode)]
    if args.plot:
        written += _plot(setup, logs, out_dir, f"{setup.robot_name} / {args.scenario} ({args.mode})")
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="qpik", description="QP-based differential inverse kinematics on MuJoCo models.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("scenarios", help="list the named scenarios")
    p.set_defaults(handler=cmd_scenarios)

    def common(p):
        p.add_argument("robot", help="arm, hexapod, or an MJCF file with the same names")
        p.add_argument("--scenario", required=True, help="scenario name (see `qpik scenarios`)")
        p.add_argument("--mode", choices=MODES, default="kinematic")
        p.add_argument("--out", help="output folder (default: out/...)")
        p.add_argument("--plot", action="store_true", help="write PNG figures")

    p = sub.add_parser("run", help="roll one controller out on a scenario")
    common(p)
    p.add_argument("--controller", default="qp",
                   help="qp, qp-hard (a scenario's QP with its top level hard), hqp (strict hierarchy), "
                        "sns (saturation in the null space), pinv (classical law), jt (Jacobian transpose), "
                        "or the peers mink, placo")
    p.add_argument("--solver", default="daqp", help="QP solver (qpsolvers name)")
    p.set_defaults(handler=cmd_run)

    p = sub.add_parser("compare", help="every controller side by side on one scenario")
    common(p)
    p.add_argument("--solvers", type=_solver_list,
                   help="comma-separated QP solvers for qp and mink (default: all installed)")
    p.set_defaults(handler=cmd_compare)
    for register in EXTRA_COMMANDS:
        register(sub)
    return parser


# Other modules add subcommands here: each a function taking the subparsers object.
EXTRA_COMMANDS: list[Callable] = []

from .calibrate import register as _register_calibrate  # noqa: E402

EXTRA_COMMANDS.append(_register_calibrate)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return args.handler(args)
    except _UsageError as exc:
        print(f"{exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except QpikError as exc:
        print(f"qpik: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("qpik: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `qpik compare ... | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
