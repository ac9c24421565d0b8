"""The ``furuta-cosim`` command: parses, dispatches, and turns errors into one clear line.

Heavy modules are imported inside the handlers so that ``--help`` stays instant. Exit codes:
0 success, 1 a check or requirement failed, 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


def _parameters(args) -> dict:
    from furuta_cosim.fmu.plants import load_plant

    plant = load_plant(args.params)
    return dict(plant.parameters)


def cmd_build_fmu(args) -> int:
    from furuta_cosim.fmu.exporter import build_fmu

    path = build_fmu(args.model, output=args.output, log=lambda line: print(line, file=sys.stderr))
    print(path)
    return 0


def cmd_linearize(args) -> int:
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.linearize import linearize
    from furuta_cosim.fmu.plants import load_plant

    plant = load_plant(args.params)
    fmu = build_fmu(plant)
    result = linearize(fmu, parameters=dict(plant.parameters),
                       inputs={name: 0.0 for name in args.inputs} if args.inputs else None)
    if args.json:
        print(json.dumps(result.as_dict()))
        return 0
    import numpy as np

    with np.printoptions(precision=5, suppress=True, linewidth=120):
        print(f"linearization of {fmu.name} with {plant.name}"
              + (f" (discrete, period {result.period})" if result.period else ""))
        print(f"states:  {result.states}\ninputs:  {result.inputs}\noutputs: {result.outputs}")
        for name in "ABCD":
            print(f"{name} =\n{getattr(result, name)}")
    return 0


def cmd_validate_fmu(args) -> int:
    from furuta_cosim.fmu.check import validate

    findings = validate(args.path)
    width = max(len(f.check) for f in findings)
    for finding in findings:
        status = {True: "ok  ", False: "FAIL", None: "skip"}[finding.ok]
        print(f"{status}  {finding.check:{width}s}  {finding.detail}")
    failed = [f for f in findings if f.ok is False]
    print(f"{args.path}: {'problems found' if failed else 'valid'}")
    return EXIT_FAILED if failed else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="furuta-cosim",
        description="Co-simulation toolchain for the Furuta pendulum and other underactuated plants.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = commands.add_parser("build-fmu", help="build a plant FMU (cached) and print its path")
    p.add_argument("model", nargs="?", default="furuta",
                   help="model or plant file: furuta (default), table-literal, toy, or a .yaml path")
    p.add_argument("-o", "--output", help="also copy the FMU to this file or folder")
    p.set_defaults(handler=cmd_build_fmu)

    p = commands.add_parser("linearize", help="linearize a plant FMU at its start point")
    p.add_argument("--params", default="paper-calibrated",
                   help="parameter set or plant file (default: paper-calibrated)")
    p.add_argument("--inputs", nargs="+", help="inputs that make B's columns (default: all)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=cmd_linearize)

    p = commands.add_parser("validate-fmu", help="validate an FMU: fmpy, smoke runs, Ecos")
    p.add_argument("path", help="the .fmu file")
    p.set_defaults(handler=cmd_validate_fmu)
    return parser


def main(argv: list[str] | None = None) -> int:
    from furuta_cosim.errors import ConfigError, DesignError, FmuError

    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except (ConfigError, DesignError) as error:
        for line in str(error).splitlines():
            print(f"error: {line}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FmuError as error:
        print(f"error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
