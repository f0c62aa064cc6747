"""The ``qpik calibrate`` command: hexapod geometric identification (docs/calibration.md).

    qpik calibrate [--method linear|gauss-newton|lm] [--poses seed|N | --pose-file FILE]
                   [--params legs|legs+offsets|full|GROUP+GROUP...] [--noise-um SIGMA]
                   [--seed S] [--repeats R] [--out DIR] [--plot] [--quiet]

Prints a table (leg, parameter, imposed, estimated, error, relative error) and writes
``DIR/calibration.json`` (and ``DIR/calibration.png`` with ``--plot``), all or nothing
(:class:`qpik.app.output.OutputFolder`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InvalidInput
from ..rollout.io import save_figure, write_json

if TYPE_CHECKING:
    from ..robots.hexapod.calibration import Calibration

DEFAULT_OUT = "out/calibrate"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The ``calibrate`` subcommand's options (on the parser ``qpik`` made for it)."""
    from ..robots.hexapod.calibration import METHODS, PARAMETER_SETS

    p.add_argument("--method", choices=METHODS, default="linear",
                   help="linear: the source's first-order least squares; gauss-newton: undamped "
                        "iterations to convergence; lm: scipy's Levenberg-Marquardt")
    poses = p.add_mutually_exclusive_group()
    poses.add_argument("--poses", default="seed",
                       help="'seed' (the source's four poses, docs/calibration.md) or N random reachable "
                            "poses about home")
    poses.add_argument("--pose-file", type=Path,
                       help="CSV (one pose a line) or JSON list of [x, y, z, thx, thy, thz] (m, deg)")
    p.add_argument("--params", default="legs",
                   help=f"identified errors: {', '.join(PARAMETER_SETS)} (= legs+offsets+points), or "
                        "groups legs, offsets, points, zeros (encoder zero errors) joined by '+'")
    p.add_argument("--noise-um", type=float, default=0.0, help="σ of Gaussian stroke noise (µm)")
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the random poses and the noise (default: 0); an error when there is "
                        "neither (seed poses, no noise)")
    p.add_argument("--repeats", type=int, default=1,
                   help="noise realisations for the Monte-Carlo spread (same poses); needs --noise-um > 0")
    p.add_argument("--out", type=Path, default=Path(DEFAULT_OUT), help="output folder, replaced whole if it holds an earlier output")
    p.add_argument("--plot", action="store_true",
                   help="write calibration.png (imposed vs estimated, error vs number of poses)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(handler=cmd_calibrate)


def load_poses(path: str | Path) -> np.ndarray:
    """Poses from a JSON list of [x, y, z, thx, thy, thz] or a CSV with one pose a line (# comments)."""
    from ..robots.hexapod.calibration import validate_poses

    path = Path(path)
    try:
        text = path.read_text()
        if path.suffix.lower() == ".json":
            rows = json.loads(text)
        else:
            rows = [[float(v) for v in line.split(",")] for line in text.splitlines()
                    if line.strip() and not line.lstrip().startswith("#")]
        return validate_poses(rows)
    except OSError as exc:
        raise InvalidInput(f"cannot read pose file {path}: {exc.strerror}") from None
    except (ValueError, TypeError) as exc:  # bad JSON/CSV/encoding, ragged rows, wrong width
        raise InvalidInput(f"malformed pose file {path}: {exc}") from None


def parse_poses_option(text: str) -> str | int:
    """``--poses``: 'seed' or an integer (validated by the library: N ≥ 1)."""
    if text == "seed":
        return text
    try:
        return int(text)
    except ValueError:
        raise InvalidInput(f"--poses must be 'seed' or a number of poses, got {text!r}") from None


def to_json(result: Calibration) -> dict:
    """The ``calibration.json`` document of a :class:`~qpik.robots.hexapod.calibration.Calibration` (µm, %, m, deg)."""
    def um(values):  # 1e-12 µm = 1e-18 m: below the 4e-17 m resolution of a 0.2 m stroke
        return None if values is None else [None if np.isnan(v) else round(float(v) * 1e6, 12) for v in values]

    mc = result.monte_carlo
    return {
        "method": result.method, "params": result.params.label, "parameters": result.params.names,
        "poses": result.poses.tolist(), "pose_source": result.pose_source,
        "noise_um": result.noise_um, "seed": result.seed,
        "dl_imposed_um": um(result.imposed), "dl_reference_um": um(result.reference),
        "dl_estimated_um": um(result.fit.theta), "dl_error_um": um(result.error),
        "relative_error_pct": [None if np.isnan(v) else float(v) for v in result.relative_error_pct],
        "residual_rms_um": result.fit.residual_rms * 1e6,
        "condition_number": result.ident.condition_number, "rank": result.ident.rank,
        "n_parameters": result.params.size,
        "singular_values": result.ident.singular_values.tolist(),
        "fixed_parameters": result.ident.fixed, "null_space": result.ident.null_vectors(),
        "iterations": result.fit.iterations, "function_evaluations": result.fit.evaluations,
        "covariance_std_um": um(result.covariance_std),
        "repeats": 1 if mc is None else len(mc),
        "dl_std_um": um(result.monte_carlo_std),
        "dl_mean_um": None if mc is None else um(mc.mean(axis=0)),
    }


def format_report(result: Calibration) -> str:
    """The table and the identifiability / spread notes printed by ``qpik calibrate``."""
    names, legs = result.params.names, result.params.leg_numbers
    noisy, mc_std = result.noise_um > 0, result.monte_carlo_std
    head = f"{'leg':>3}  {'parameter':9s} {'imposed µm':>12} {'estimated µm':>13} {'error µm':>12} {'rel. error %':>13}"
    head += f" {'cov. std µm':>12}" if noisy else ""
    head += f" {'MC std µm':>10}" if mc_std is not None else ""
    lines = [f"hexapod calibration: method {result.method}, params {result.params.label}, "
             f"{len(result.poses)} poses ({result.pose_source}), noise σ = {result.noise_um:g} µm", head]
    rel = result.relative_error_pct
    for j, name in enumerate(names):
        if not result.ident.free[j]:
            lines.append(f"{legs[j]:>3}  {name:9s} {'fixed at 0 (not identifiable)':>52}")
            continue
        row = (f"{legs[j]:>3}  {name:9s} {result.reference[j] * 1e6:12.6f} {result.fit.theta[j] * 1e6:13.6f} "
               f"{result.error[j] * 1e6:12.3e} {rel[j]:13.3e}")
        row += f" {result.covariance_std[j] * 1e6:12.4f}" if noisy else ""
        row += f" {mc_std[j] * 1e6:10.4f}" if mc_std is not None else ""
        lines.append(row)
    ident = result.ident
    lines.append(f"identification Jacobian: rank {ident.rank}/{result.params.size}, condition number "
                 f"{ident.condition_number:.4g}; residual rms {result.fit.residual_rms * 1e6:.3g} µm; "
                 f"{result.fit.iterations} iteration(s), {result.fit.evaluations} model evaluation(s)")
    if ident.fixed:
        lines.append("not identifiable from strokes at these poses (null space of the Jacobian), "
                     "fixed at 0 as the gauge:")
        for name, vec in zip(ident.fixed, ident.null_vectors()):
            combo = " + ".join(f"{-c:g}·{n}" for n, c in vec.items() if n != name).replace("+ -", "- ")
            lines.append(f"  a change of {name} acts on the strokes like {combo}")
        lines.append("  imposed column: the imposed errors moved along that null space into the gauge "
                     "(to first order; exact where the degeneracy is linear, as offsets vs zeros)")
    per_leg = result.params.per_leg
    if per_leg > len(result.poses):
        lines.append(f"too few poses: each stroke depends on its own leg's {per_leg} parameters only, "
                     f"so each leg needs at least {per_leg} poses (here {len(result.poses)})")
    return "\n".join(lines)


def check_options(args: argparse.Namespace, poses) -> None:
    """Options that would be silently ignored are an error instead."""
    if args.repeats > 1 and not args.noise_um > 0:
        raise InvalidInput("--repeats draws noise realisations: give --noise-um > 0 "
                           "(without noise every repeat is the same)")
    if args.seed is not None and isinstance(poses, str) and not args.noise_um > 0:
        raise InvalidInput("--seed seeds random poses (--poses N) and noise (--noise-um); "
                           "with the seed poses and no noise there is nothing random")


def cmd_calibrate(args: argparse.Namespace) -> int:
    from ..extras import require
    from ..robots.hexapod.calibration import calibrate
    from .output import OutputFolder
    from .progress import StepBars, wanted

    if args.plot:
        require("matplotlib", "qpik calibrate --plot")

    poses = load_poses(args.pose_file) if args.pose_file else parse_poses_option(args.poses)
    check_options(args, poses)
    seed = 0 if args.seed is None else args.seed
    guard = getattr(args, "interrupt_guard", None)
    with OutputFolder(args.out, guard) as out, StepBars(wanted(args.quiet), unit="fit") as bars:
        result = calibrate(args.method, poses, params=args.params, noise_um=args.noise_um,
                           seed=seed, repeats=args.repeats, progress=bars.callback("noise draws"))
        figure = None
        if args.plot:
            from .calibration_plots import plot_calibration

            figure = plot_calibration(result, progress=bars.callback("error vs number of poses"))
        bars.close()
        print(format_report(result))
        write_json(out.path("calibration.json"), to_json(result))
        if figure is not None:
            save_figure(figure, out.path("calibration.png"))
        written = out.commit()
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0
