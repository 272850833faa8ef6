"""`pursuit-mj bench <target>`: speed benchmarks (they print measurements; they are not tests).

Targets are the modules of the package `pursuit_cli.benchmarks`, found when the parser is
built: `pursuit_cli/benchmarks/physics.py` is `pursuit-mj bench physics`. To add a target
(say `env`), create `pursuit_cli/benchmarks/env.py` defining

    HELP = "one line for `pursuit-mj bench --help`"
    def add_arguments(parser: argparse.ArgumentParser) -> None: ...   # its flags
    def run(args: argparse.Namespace) -> int: ...                     # measure, print, exit code

and nothing else needs editing. `run` raises ValueError on bad input (exit code 2, one
line). Helpers for isolated runs, peak memory and tables are in `pursuit_cli.benchmarks`.
Modules whose names start with an underscore are not targets.
"""

from __future__ import annotations

import importlib
import pkgutil

from . import benchmarks


def targets() -> dict[str, object]:
    """Benchmark target name -> its module, in name order."""
    names = sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__) if not m.name.startswith("_"))
    return {name: importlib.import_module(f"{benchmarks.__name__}.{name}") for name in names}


def register(sub) -> None:
    found = targets()
    p = sub.add_parser("bench", help=f"speed benchmarks: {', '.join(found)}", description=__doc__.split("\n\n", 1)[0])
    tsub = p.add_subparsers(dest="bench_target", metavar="<target>")
    tsub.required = True
    for name, module in found.items():
        tp = tsub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(tp)
        tp.set_defaults(func=module.run)
