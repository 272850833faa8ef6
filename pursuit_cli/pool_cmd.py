"""`pursuit-mj pool`: several evaluation tables (eval --out JSON files) as one, episodes pooled.

    pursuit-mj pool results/s0.json results/s1.json results/s2.json
    pursuit-mj pool results/team_s*.json results/net_s*.json --versus heuristic --out results/pooled --plots plots/

Tables run with different --seed hold different episodes; pooled, each row has them all (an
episode in two files counts once), and every policy is paired with the reference on the
episodes both played (pursuit_mj/pooling.py).
"""

from __future__ import annotations

import dataclasses

from pathlib import Path

from pursuit_mj.io_utils import check_writable, check_writable_folder, no_new_empty_folders
from .common import (check_out_prefix, counted, path_arg, pick_versus, refuse_a_file_given_twice, refuse_replacing_what_is_no_table,
                     refuse_writing_an_input)


def register(sub) -> None:
    p = sub.add_parser(
        "pool",
        help="pool the episodes of several evaluation tables (eval --out JSON files) into one table",
        description="Read evaluation JSON files of one task (e.g. the same policies run with different --seed), "
                    "print one table over all their episodes (an episode in two files counts once) and pair every "
                    "policy with the reference on the episodes both played.",
    )
    p.add_argument("files", nargs="+", type=path_arg, metavar="FILE.json", help="tables written by `pursuit-mj eval --out/--json`")
    p.add_argument("--versus", metavar="POLICY",
                   help="pair every other policy with this one (default: heuristic when it is there with others; 'none': no pairing)")
    p.add_argument("--out", metavar="PREFIX", help="write PREFIX.csv and PREFIX.json")
    p.add_argument("--plots", metavar="DIR", help="write one bar chart per metric (PNG) into DIR")
    p.set_defaults(func=run)


def run(args) -> int:
    """The pool command. Refused or stopped before it wrote, it leaves none of the folders it made for
    --out or --plots (io_utils.no_new_empty_folders)."""
    with no_new_empty_folders():
        return _run(args)


def _run(args) -> int:
    from pursuit_mj.comparison import format_pairs, one_fidelity, paired_heading, pairs_to_dicts
    from pursuit_mj.evaluation import format_table, plot_rows, write_csv, write_json
    from pursuit_mj.pooling import not_paired, not_paired_text, pool_tables, pooled_pairs

    if args.out:
        check_out_prefix(args.out)  # a usage error, before the tables are read
    refuse_a_file_given_twice("", [(text, Path(text)) for text in args.files])
    if args.out:  # a usage error too: pool s0.json s1.json --out s0 wrote over s0.json
        refuse_writing_an_input([(f"--out {args.out} (it writes {args.out}{suffix})", Path(args.out + suffix))
                                 for suffix in (".csv", ".json")], [(text, text) for text in args.files])
        refuse_replacing_what_is_no_table([(f"--out {args.out}", Path(args.out + suffix)) for suffix in (".csv", ".json")])
    pooled = pool_tables(args.files)
    labels = list(dict.fromkeys(r.policy for r in pooled.rows))
    versus = pick_versus(args.versus, labels, "these tables", "(a table that holds another)")
    if args.out:
        for suffix in (".csv", ".json"):
            check_writable(Path(args.out + suffix), "--out")
    if args.plots:
        check_writable_folder(args.plots, "--plots")
    for note in pooled.notes:
        print(note)
    task = f", {pooled.task_name}" if pooled.task_name else ""  # as eval's heading named it
    print(f"pooled {counted(len(args.files), 'table')}{one_fidelity(pooled.rows, ', every row')}{task}")
    print(format_table(pooled.rows))
    meta: dict = {"pooled_from": list(args.files), **pooled.meta}
    if versus is not None:
        pairs = pooled_pairs(pooled.rows, versus, pooled.max_steps, pooled.meta["layout_identity"])
        print("\n" + paired_heading(versus, "the episodes both played", pairs, pooled.max_steps))
        print(format_pairs(pairs))
        meta["paired"] = pairs_to_dicts(pairs)
        alone = not_paired(pooled.rows, versus, pooled.max_steps, pooled.meta["layout_identity"])
        if alone:  # else a policy of another seed's tables vanished from the comparison without a word
            print(not_paired_text(alone, versus, pooled.rows, pooled.meta["layout_identity"]))
            meta["not_paired"] = [{"policy": r.policy, "layout": r.layout, "fidelity": r.fidelity} for r in alone]
    if args.out:
        print(f"wrote {write_csv(pooled.rows, args.out + '.csv')}")
        print(f"wrote {write_json(pooled.rows, args.out + '.json', meta=meta | {'config': pooled.config})}")
    if args.plots:
        shown = pooled.rows
        if len({r.fidelity for r in shown}) > 1:  # a bar per policy and fidelity: "heuristic (point)"
            shown = [dataclasses.replace(r, policy=f"{r.policy} ({r.fidelity})") for r in shown]
        for path in plot_rows(shown, args.plots):
            print(f"wrote {path}")
    return 0
