"""`pursuit-mj config`: print the resolved task config."""

from __future__ import annotations

from ..config import dump_yaml
from .common import add_task_args, task_config_from_args


def register(sub) -> None:
    p = sub.add_parser("config", help="print the resolved task config (defaults <- files <- flags <- --set)")
    add_task_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    args.show_config = False
    print(dump_yaml(task_config_from_args(args)), end="")
    return 0
