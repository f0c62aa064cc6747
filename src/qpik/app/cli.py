"""The ``qpik`` command (``python -m qpik`` is the same).

    qpik scenarios
    qpik run ROBOT --scenario NAME [--controller {qp,qp-hard,hqp,sns,pinv,jt,mink,placo}] [--solver S]
             [--mode {kinematic,physics}] [--out DIR] [--plot] [--video FILE] [--quiet]
    qpik compare ROBOT --scenario NAME [--solvers daqp,osqp,...] [--mode M] [--out DIR]
             [--plot] [--video FILE] [--quiet]
    qpik calibrate [...]           (see ``qpik calibrate --help``)
    qpik sweep ROBOT --targets N [--controllers qp,pinv] [--seed S] [--out DIR] [--ray ADDRESS|auto]
             [--chunk K] [--workers W] [--quiet]   (see :mod:`qpik.app.sweep`)
    qpik --version

Contract: bad input gives one line on stderr and exit code 2, never a traceback, and
nothing written; the output folder is checked before any work. A run whose controller
fails after its first step (an infeasible QP, a divergence) writes the steps before,
marked partial, and exits with code 1. Ctrl-C stops the command within a step (exit code
130; SIGTERM the same, exit code 143) and leaves nothing of its output behind (an earlier
output it was to replace stays as it was): every file is
assembled in a hidden folder next to the target and moved into place at the end
(:mod:`qpik.app.output`, :mod:`qpik.app.interrupt`). Runs show a progress bar on stderr
when it is a terminal (``--quiet`` hides it).

Start-up is kept light: this module imports nothing heavy (no MuJoCo, NumPy, SciPy);
each subcommand declares its options, whose help lists the installed solvers and the
registered scenarios, only when it is the one invoked.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Callable, Sequence

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143  # 128 + SIGTERM
EXIT_STOPPED = 1  # `qpik run`: the controller failed mid-run; the partial log is written
MODES = ("kinematic", "physics")  # qpik.rollout.MODES, without importing the rollout at start-up


class _UsageError(Exception):
    pass


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows "(default: X)" where there is a default worth saying (not None, not a flag's False)."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False or "(default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line usage error and options declared on first use.

    ``populate(parser)`` (if given) adds the parser's arguments when it first parses or
    prints its help: a subcommand's options (and the imports its help needs) cost
    nothing unless that subcommand runs.
    """

    def __init__(self, *args, populate: Callable[[argparse.ArgumentParser], None] | None = None, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)
        self._populate = populate

    def _ensure_populated(self) -> None:
        if self._populate is not None:
            populate, self._populate = self._populate, None
            populate(self)

    def parse_known_args(self, args=None, namespace=None):
        self._ensure_populated()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self._ensure_populated()
        return super().format_help()

    def error(self, message: str):
        raise _UsageError(f"{self.prog}: {message}")


def _solver_list(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of solver names")
    return names


def _catalogue() -> tuple[list[str], str]:
    """Installed solvers, and the scenario names by robot (for help texts)."""
    from ..scenario import scenarios
    from ..solvers import available_solvers

    by_robot: dict[str, list[str]] = {}
    for info in scenarios().values():
        by_robot.setdefault(info.robot, []).append(info.name)
    listing = "; ".join(f"{robot}: {', '.join(names)}" for robot, names in by_robot.items())
    return available_solvers(), listing


ROBOT_HELP = ("arm or hexapod (the bundled scenes), or the path of an MJCF file to run the "
              "scenario on instead: it must define every name the scenario uses (arm: joints "
              "theta1, theta2, theta3, d4 and site end_effector; hexapod: the generated scene's "
              "slider, universal-joint and platform joints, sites and loop equalities) and the "
              "qpik_velocity_limit_<joint> numerics")
MODE_HELP = ("kinematic: integrate the commanded joint velocity (the source's scheme); physics: "
             "MuJoCo steps the scene, whose position (and velocity) servos track the command")


def _robot_and_scenario(p: argparse.ArgumentParser, scenario_listing: str) -> None:
    p.add_argument("robot", help=ROBOT_HELP)
    p.add_argument("--scenario", required=True, metavar="NAME",
                   help=f"scenario ({scenario_listing}; `qpik scenarios` describes them)")


def _outputs(p: argparse.ArgumentParser, out_default: str) -> None:
    p.add_argument("--mode", choices=MODES, default="kinematic", help=MODE_HELP)
    p.add_argument("--out", metavar="DIR", help=f"output folder, replaced whole if it holds an earlier output "
                                                f"(default: {out_default})")
    p.add_argument("--plot", action="store_true", help="also write PNG figures")
    p.add_argument("--video", metavar="FILE", type=Path,
                   help="also write a video of the rollout (.mp4 or .gif; headless: MUJOCO_GL=egl)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _run_arguments(p: argparse.ArgumentParser) -> None:
    from .kinds import KINDS, SOLVER_KINDS

    solvers, listing = _catalogue()
    _robot_and_scenario(p, listing)
    p.add_argument("--controller", default="qp", metavar="NAME",
                   help=f"one of {', '.join(KINDS)}: "
                        + ", ".join(f"{name} ({kind.description})" for name, kind in KINDS.items()))
    p.add_argument("--solver", default=None, metavar="NAME",
                   help=f"QP solver of {' and '.join(SOLVER_KINDS)}, one of the installed {', '.join(solvers)} "
                        "(default: daqp); an error with the other controllers")
    _outputs(p, "out/run-SCENARIO-CONTROLLER-MODE")
    p.set_defaults(handler=cmd_run)


def _compare_arguments(p: argparse.ArgumentParser) -> None:
    solvers, listing = _catalogue()
    _robot_and_scenario(p, listing)
    p.add_argument("--solvers", type=_solver_list, metavar="S1,S2",
                   help=f"comma-separated QP solvers for qp and mink (default: every installed one: "
                        f"{','.join(solvers)})")
    _outputs(p, "out/compare-SCENARIO-MODE")
    p.set_defaults(handler=cmd_compare)


def _calibrate_arguments(p: argparse.ArgumentParser) -> None:
    from .calibrate import add_arguments

    add_arguments(p)


def _sweep_arguments(p: argparse.ArgumentParser) -> None:
    from .sweep.command import add_arguments

    add_arguments(p)


def _bars(args):
    from .progress import StepBars, wanted

    return StepBars(wanted(args.quiet))


def _plot(setup, logs, out_dir: Path, title: str) -> list[Path]:
    from .plotting import plot_logs  # matplotlib only when asked for

    return plot_logs(logs, setup.plot_joints, out_dir, title)


def _video(setup, logs, out, args, caption: str) -> None:
    from .progress import StepBars, wanted
    from .video import render_comparison

    with StepBars(wanted(args.quiet), unit="frame") as bars:
        render_comparison(setup.robot.model, logs, out.file(args.video), caption=caption,
                          progress=bars.callback(f"video {args.video.name}"))


def _start_output(args, default: str):
    """The output folder (and video file), checked before any work, as are the extras
    that ``--plot`` and ``--video`` need."""
    from ..extras import require
    from .output import OutputFolder

    if getattr(args, "plot", False):
        require("matplotlib", "--plot")
    out = OutputFolder(args.out or default, args.interrupt_guard)
    if getattr(args, "video", None) is not None:
        from .video import check_video_path, probe_gl

        try:
            out.add_file(check_video_path(args.video))
            probe_gl()
        except BaseException:
            out.discard()
            raise
    return out


def _print_note(note: str | None) -> None:
    if note is not None:
        print(note)


def cmd_scenarios(args) -> int:
    from ..scenario import scenarios

    known = scenarios()
    width = max(len(n) for n in known)
    for info in known.values():
        print(f"{info.name.ljust(width)}  {info.robot:8s} {info.description}")
    return 0


def cmd_run(args) -> int:
    from ..errors import InvalidInput
    from .kinds import SOLVER_KINDS, uses_solver
    from .runs import format_table, level_note, run, run_label

    if args.solver is not None and not uses_solver(args.controller):
        raise InvalidInput(f"--solver applies to {' and '.join(SOLVER_KINDS)} only; controller "
                           f"{args.controller!r} uses no QP solver of ours")
    solver = args.solver or "daqp"
    out = _start_output(args, f"out/run-{args.scenario}-{args.controller}-{args.mode}")
    with out, _bars(args) as bars:
        label = run_label(args.controller, solver if uses_solver(args.controller) else "none")
        setup, log = run(args.robot, args.scenario, args.controller, solver, args.mode, on_failure="stop",
                         progress=bars.callback(label))
        bars.close()
        summary = log.summary()
        print(format_table([summary]))
        _print_note(level_note([summary], args.mode))
        log.save(out.staging)
        title = f"{setup.robot_name} / {args.scenario} / {args.controller} ({args.mode})"
        if args.plot:
            _plot(setup, [log], out.staging, title)
        if args.video is not None:
            _video(setup, [log], out, args, title)
        written = out.commit()
    print(f"wrote {', '.join(str(p) for p in written)}")
    if not log.completed:  # the steps before the stop are written, marked partial
        print(f"qpik: the run {summary.status}; its log is partial: {log.failure}", file=sys.stderr)
        return EXIT_STOPPED
    return 0


def cmd_compare(args) -> int:
    from .runs import compare, format_table, level_note, write_compare

    out = _start_output(args, f"out/compare-{args.scenario}-{args.mode}")
    with out, _bars(args) as bars:
        setup, logs, notes = compare(args.robot, args.scenario, args.solvers, args.mode,
                                      progress=bars if bars.enabled else None)
        bars.close()
        summaries = [log.summary() for log in logs]
        title = f"{setup.robot_name} / {args.scenario} ({args.mode})"
        print(f"{setup.robot_name} / {args.scenario} ({args.mode} mode)")
        print(format_table(summaries))
        for note in notes:
            print(note)
        _print_note(level_note(summaries, args.mode))
        write_compare(out.staging, setup.robot_name, args.scenario, summaries, args.mode)
        if args.plot:
            _plot(setup, logs, out.staging, title)
        if args.video is not None:
            _video(setup, logs, out, args, title)
        written = out.commit()
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = _Parser(prog="qpik", description="QP-based differential inverse kinematics on MuJoCo models: "
                     "run and compare controllers on named scenarios, calibrate the hexapod.")
    parser.add_argument("--version", action="version", version=f"qpik {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")
    p = sub.add_parser("scenarios", help="list the named scenarios")
    p.set_defaults(handler=cmd_scenarios)
    sub.add_parser("run", help="roll one controller out on a scenario", populate=_run_arguments)
    sub.add_parser("compare", help="every controller on one scenario, side by side",
                   populate=_compare_arguments)
    sub.add_parser("calibrate", help="identify the hexapod's geometric errors from strokes",
                   populate=_calibrate_arguments)
    sub.add_parser("sweep", help="a Monte-Carlo study over the workspace, as chunks of batched worlds",
                   populate=_sweep_arguments)
    for register in EXTRA_COMMANDS:
        register(sub)
    return parser


# Other modules may add subcommands here: each a function taking the subparsers object.
EXTRA_COMMANDS: list[Callable] = []


def main(argv: Sequence[str] | None = None) -> int:
    from ..errors import QpikError
    from .interrupt import InterruptGuard, Terminated

    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        # The guard comes first: threads started later (NumPy's BLAS pool) inherit its mask.
        with InterruptGuard() as guard:
            if any(a == "--video" or a.startswith("--video=") for a in argv):
                from .video import prefer_headless_gl

                prefer_headless_gl()  # before MuJoCo is imported: it reads MUJOCO_GL once
            args = build_parser().parse_args(argv)
            args.interrupt_guard = guard  # output folders shield their final move with it
            return args.handler(args)
    except _UsageError as exc:
        print(f"{exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except QpikError as exc:
        print(f"qpik: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print(f"qpik: {'terminated' if terminated else 'interrupted'}; nothing written", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. `qpik compare ... | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
