"""`pursuit-mj config`: print the resolved task config."""

from __future__ import annotations

from pursuit_mj.config import dump_yaml
from pursuit_mj.env import check_task_layouts
from .common import add_task_args, task_config_from_args


def register(sub) -> None:
    p = sub.add_parser("config", help="print the resolved task config (defaults <- files <- flags <- --set)")
    add_task_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    args.show_config = False
    config = task_config_from_args(args)
    # a missing or broken layout file, or one that cannot hold the task, is an error here too, as in every run
    check_task_layouts(config)
    print(dump_yaml(config), end="")
    return 0
