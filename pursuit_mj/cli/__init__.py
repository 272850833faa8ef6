"""The `pursuit-mj` console command. Each subcommand lives in its own module of this package.

A subcommand module defines `register(subparsers)`, which adds its parser and sets
`func=run` on it; `run(args) -> int` does the work. Bad input raises ValueError (ConfigError,
LayoutError ...), which `main` prints as one clear line with exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: subcommand modules, in the order `--help` lists them
SUBCOMMANDS = [
    "demo",
    "config_cmd",
    "layout_cmd",
    "simulate",
    "bench",
    "eval_cmd",
    "train_cmd",
    "study",
    "render_cmd",
    "plot_cmd",
    "fly_cmd",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pursuit-mj",
        description="Quadrotor pursuit-evasion in MuJoCo: layouts, physics, training, evaluation, rendering, flights.",
    )
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    sub.required = True
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue  # a subcommand still being written
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"pursuit-mj {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"pursuit-mj {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
