"""``femphase ode --rate R -o OUT``: solve the paper's minimal model of the shape oscillations
(:mod:`femphase.model.minimal`) and write ode.csv and ode.json."""

from __future__ import annotations

import argparse

from femphase.errors import SceneError
from femphase.io.files import output_directory, writable_directory
from femphase.model.minimal import (
    DEFAULT_INITIAL_ELONGATION,
    DEFAULT_PERIODS,
    MinimalModelParameters,
    ParameterError,
    period,
    solve_minimal_model,
    write_solution,
)

__all__ = ["OUTPUTS", "register", "run"]

#: The files a solution writes (:func:`~femphase.model.minimal.write_solution`).
OUTPUTS = ("ode.csv", "ode.json")


def run(args: argparse.Namespace) -> int:
    """`femphase ode`: solve the minimal model and write ode.csv and ode.json to args.output."""
    args.output = output_directory(args.output)
    written = [name for name in OUTPUTS if (args.output / name).exists()]
    if written and not args.overwrite:
        raise SceneError("-o", str(args.output), f"a directory without a solution: it holds {', '.join(written)}; "
                         "replace them with --overwrite")
    try:
        parameters = MinimalModelParameters(A=args.A, epsilon=args.epsilon, K=args.K, k=args.k)
        t_end = DEFAULT_PERIODS * period(args.rate, args.k) if args.t_end is None else args.t_end
        solution = solve_minimal_model(
            args.rate, t_end, parameters=parameters, initial_elongation=args.initial_elongation
        )
    except ParameterError as exc:  # every parameter is an option of the same name
        raise exc.as_option() from None
    writable_directory(args.output)  # a -o that cannot be made is named as the option
    write_solution(solution, args.output)
    print(f"wrote {args.output / 'ode.csv'} and {args.output / 'ode.json'}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `ode` subcommand to the femphase command line."""
    defaults = MinimalModelParameters()
    parser = subparsers.add_parser(
        "ode",
        help="solve the paper's minimal ODE model of the shape oscillations",
        description="Solve the minimal model r(t), θ(t), φ(t) of Hadjifrangiskou, Valani & "
        "Pinto and write ode.csv and ode.json.",
    )
    parser.add_argument("--rate", type=float, required=True,
                        help="shear rate γ̇ (> 0; the scenes' velocity scale, the number a scene's flow.rate gives: "
                             "ω = kγ̇ per time unit)")
    parser.add_argument("-o", "--output", required=True,
                        help="output directory (ode.csv, ode.json: docs/outputs.md)")
    parser.add_argument("--overwrite", action="store_true", help="replace the ode.csv and ode.json it holds")
    parser.add_argument(
        "--t-end", type=float, default=None,
        help=f"final time (time units; default: {DEFAULT_PERIODS} periods π/(k γ̇))",
    )
    parser.add_argument("--A", type=float, default=defaults.A, help="lattice drive A (default %(default)s)")
    parser.add_argument("--epsilon", type=float, default=defaults.epsilon, help="ε of −ε r³ (default %(default)s)")
    parser.add_argument("--K", type=float, default=defaults.K, help="K of K/r (default %(default)s)")
    parser.add_argument("--k", type=float, default=defaults.k, metavar="k", help="ω = k γ̇ (default %(default)s)")
    parser.add_argument(
        "--initial-elongation", type=float, default=DEFAULT_INITIAL_ELONGATION,
        help="r(0) = AR − 1 (> 0; default %(default)s)",
    )
    parser.set_defaults(func=run)
