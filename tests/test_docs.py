"""Every `pursuit-mj ...` command the docs show still works with today's command line.

Commands are taken from README.md, pretrained/README.md, docs/*.md, the comments of
configs/**/*.yaml, the examples in every subcommand's --help, and the example lines of the
code (module docstrings, the next steps `pursuit-mj demo` prints). Each is parsed by the real
parser (a renamed or removed flag fails here), and its config (the task's, or the train
config's for `train`) is resolved, so a renamed config key in `--set` fails too.
"""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

from pursuit_cli import build_parser
from pursuit_cli.common import task_config_from_args
from pursuit_cli.train_cmd import _flags, _flags_typed
from train.config import load_train_config

ROOT = Path(__file__).resolve().parent.parent
DOCS = ["README.md", "pretrained/README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
#: subcommands whose task flags resolve through common.task_config_from_args
TASK_COMMANDS = {"config", "simulate", "eval", "study", "render", "demo"}
#: written in place of a placeholder word (MODEL, DIR, B ...) so that the flags around it still parse
PLACEHOLDER = re.compile(r"^[A-Z][A-Z_]*$")
#: a placeholder FILE.py:NAME reference (--policy, --reward)
PLACEHOLDER_REF = re.compile(r"^[A-Z][A-Z_]*\.py:[A-Z][A-Z_]*$")


def _documented_files() -> dict[str, str]:
    """The Python files the docs write out (a ```python block whose first line is `# NAME.py`), by name."""
    files = {}
    for doc in DOCS:
        files.update(re.findall(r"```python\n# (\w+\.py)\n(.*?)```", (ROOT / doc).read_text(), re.S))
    return files


def _from_markdown(text: str) -> list[str]:
    """Commands in code blocks (one a line, `\\` continuations joined, comments cut) and in inline code."""
    found = []
    for block in re.findall(r"```[a-z]*\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("pursuit-mj "):
                found.append(line)
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    found += [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", prose) if span.startswith("pursuit-mj ")]
    return found


def _from_yaml_comments(text: str) -> list[str]:
    return [m.group(1).split(" #")[0].strip() for m in re.finditer(r"#\s*(pursuit-mj [^\n]*)", text)]


def _from_code(text: str) -> list[str]:
    return [m.group(1).split(" #")[0].strip() for m in re.finditer(r"^\s*(pursuit-mj [a-z][^\n]*)", text, re.M)]


def _from_help(parser: argparse.ArgumentParser) -> list[str]:
    found = []
    for text in (parser.description or "", parser.epilog or ""):
        found += [m.group(1).strip() for m in re.finditer(r"^\s*(pursuit-mj [^\n]*)", text, re.M)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found += _from_help(sub)
    return found


def _alternatives(command: str) -> list[str]:
    """`pursuit-mj bench physics | env | render` as the three commands it stands for."""
    first, *rest = command.split(" | ")
    stem = first.rsplit(" ", 1)[0]
    return [first, *(f"{stem} {alt}" for alt in rest)]


def _documented() -> list[tuple[str, str]]:
    found = [(name, cmd) for name in DOCS for cmd in _from_markdown((ROOT / name).read_text())]
    for path in sorted((ROOT / "configs").rglob("*.yaml")):
        found += [(str(path.relative_to(ROOT)), cmd) for cmd in _from_yaml_comments(path.read_text())]
    found += [("--help", cmd) for cmd in _from_help(PARSER)]
    for package in ("pursuit_cli", "pursuit_mj", "train"):
        for path in sorted((ROOT / package).rglob("*.py")):
            found += [(str(path.relative_to(ROOT)), cmd) for cmd in _from_code(path.read_text())]
    # a pattern such as `pursuit-mj <subcommand> --help` stands for no one command
    return [(where, one) for where, cmd in found if "<" not in cmd for one in _alternatives(cmd)]


def _options(parser: argparse.ArgumentParser) -> set[str]:
    """Every flag spelled out in full, of the parser and its subcommands (argparse also takes prefixes)."""
    found = set()
    for action in parser._actions:
        found |= set(action.option_strings)
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _options(sub)
    return found


PARSER = build_parser()
OPTIONS = _options(PARSER)
COMMANDS = _documented()


def test_the_docs_show_commands_of_every_kind():
    shown = {shlex.split(cmd)[1] for _, cmd in COMMANDS}
    assert {"train", "eval", "render", "fly", "layout", "plot", "study", "demo", "bench"} <= shown
    assert len(COMMANDS) > 80


@pytest.mark.parametrize("where, command", COMMANDS, ids=[f"{w}: {c[:70]}" for w, c in COMMANDS])
def test_documented_command_parses_and_resolves(where, command, capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(ROOT)  # the docs' relative paths are from the repository root
    words = [w.strip("[]") for w in shlex.split(command)[1:] if w != "..."]
    placeholders = any(PLACEHOLDER.match(w) or PLACEHOLDER_REF.match(w) for w in words)
    written = _documented_files()
    for i, word in enumerate(words):  # a file the docs write out (sight.py:sight): written, then named by its path
        key, _, value = word.rpartition("=") if words[i - 1] == "--set" else ("", "", word)
        file, _, name = value.partition(":")
        if (words[i - 1] == "--reward" or key.endswith("evader.model")) and file in written:
            (tmp_path / file).write_text(written[file])
            words[i] = f"{key}{'=' if key else ''}{tmp_path / file}:{name}"
    argv = ["1" if PLACEHOLDER.match(w) else w for w in words]
    if _names_subcommands(argv):
        return  # a mention in prose (`pursuit-mj layout show`)
    try:
        args = PARSER.parse_args(argv)
    except SystemExit as exc:
        assert exc.code == 0, f"{where}: {command!r} does not parse: {capsys.readouterr().err.strip()}"
        return  # --help
    spelled = {w.split("=")[0] for w in argv if w.startswith("-") and not w[1:2].isdigit()}
    assert spelled <= OPTIONS, f"{where}: {command!r}: {sorted(spelled - OPTIONS)} only abbreviate a flag"
    if placeholders:
        return
    if args.command == "train" and not (args.export or args.resume):
        load_train_config(args.config, args.overrides, _flags(args), _flags_typed(args))  # as -sc does, without torch
    elif args.command in TASK_COMMANDS:
        task_config_from_args(args)  # a ConfigError names the bad key


def _names_subcommands(words: list[str]) -> bool:
    """True when every word is a subcommand (or a subcommand's action) of the one before it."""
    parser = PARSER
    for word in words:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            return False
        parser = subs[0].choices[word]
    return True


def test_the_regime_table_of_docs_training_md_lists_every_train_preset_with_its_settings():
    from pursuit_mj.config import preset_names

    text = (ROOT / "docs/training.md").read_text()
    table = text.split("## Regimes", 1)[1].split("\n\n", 1)[0]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in table.splitlines() if line.startswith("| ") and
            ".yaml" in line]
    assert sorted(r[0].removesuffix(".yaml") for r in rows) == preset_names("train")
    for file, algo, observability, gamma, clip, envs, speeds in rows:
        cfg = load_train_config([ROOT / "configs/train" / file])
        assert algo.split(",")[0].split(" ")[0] == cfg.algo, file
        assert observability.split(" ")[0].strip(",") == cfg.task.observability, file
        assert float(gamma) == cfg.ppo.gamma, file
        assert (clip == "-") if cfg.algo == "dagger" else (float(clip) == cfg.ppo.clip), file
        assert int(envs) == cfg.n_envs, file
        assert [float(v) for v in speeds.split("/")] == [cfg.task.pursuer_speed, cfg.task.evader_speed], file


def test_docs_training_md_names_every_pursuit_mj_module_that_train_imports():
    import ast

    used = set()
    for path in (ROOT / "train").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "pursuit_mj":
                parts = node.module.split(".")
                used |= {parts[1]} if len(parts) > 1 else {alias.name for alias in node.names}
            elif isinstance(node, ast.Import):
                used |= {a.name.split(".")[1] for a in node.names if a.name.startswith("pursuit_mj.")}
    intro = (ROOT / "docs/training.md").read_text().split("## Commands", 1)[0]
    named = set(re.findall(r"`(\w+)`", intro))
    assert used <= named, f"docs/training.md does not name {sorted(used - named)} among the modules train/ uses"


def test_the_python_example_of_docs_evaluation_md_runs_as_written_with_fewer_episodes(monkeypatch, capsys):
    """It used a `config` it never made (NameError when pasted); run with one episode on one layout."""
    text = (ROOT / "docs" / "evaluation.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "evaluate(" in b]
    shrunk = block.replace("layouts=[0, 1, 2, 3]", "layouts=[0]").replace("episodes=150", "episodes=1")
    assert "episodes=150" in block and "episodes=150" not in shrunk
    exec(compile(shrunk, "docs/evaluation.md", "exec"), {})
    out = capsys.readouterr().out
    assert "heuristic" in out and "random" in out and "paired with heuristic" in out
    from pursuit_mj.config import load_task_config

    monkeypatch.chdir(ROOT)  # the comment's call, from the repository root
    assert load_task_config(["configs/task/hard.yaml"], ["evader_speed=0.9"]).evader_speed == 0.9


def _flag_actions(parser: argparse.ArgumentParser, path: str = "pursuit-mj"):
    """(command, action) for every flag of the parser and its subcommands, --help and --version aside."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _flag_actions(sub, f"{path} {name}")
        elif action.option_strings and not isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            yield path, action


def test_every_flag_of_every_subcommand_is_named_in_the_docs():
    """A flag shown by --help alone (fly --max-time, train --random-layout, eval -q, the layout new shapes
    were) is one a reader of the guides never meets; any one of its spellings counts. experiments.md, the
    lab notebook, does not count: it says what was run, not what a flag does."""
    guides = [doc for doc in DOCS if doc != "docs/experiments.md"]
    text = "\n".join((ROOT / doc).read_text() for doc in guides)
    missing = [f"{path} {action.option_strings[-1]}" for path, action in _flag_actions(PARSER)
               if not any(re.search(re.escape(flag) + r"(?![\w-])", text) for flag in action.option_strings)]
    assert not missing, f"flags named by no guide ({', '.join(guides)}): {missing}"


@pytest.mark.parametrize("said, count, episodes", [
    # belppo_point, seeds 0-5: 381 and 379 of 384 on layouts 0 and 3
    ("the 95 % interval of its success over all 384 episodes reaches below 98 % on layouts 0 and 3 (97.7 and 97.0 %)", 381, 384),
    ("the 95 % interval of its success over all 384 episodes reaches below 98 % on layouts 0 and 3 (97.7 and 97.0 %)", 379, 384),
    # belppo_quad: seeds 3-5 alone (188 of 192 on layout 3), and seeds 0-5 (378 of 384)
    ("four timeouts in 192: 97.9 %, its 95 % interval 94.8-99.2 %", 188, 192),
    ("over all 384 episodes the 95 % interval of its success reaches down to 96.6 % on layout 3", 378, 384),
    ("98.2 % with a 95 % interval of 97.2-98.8 %", 1131, 1152),
    # belppo_kick, seeds 0-17: layouts 0 and 3
    ("the 95 % interval on layout 0 is 98.5-99.6 %", 1143, 1152),
    ("on layout 3 it is 97.5-99.0 %", 1134, 1152),
])
def test_the_success_intervals_pretrained_readme_quotes_are_the_wilson_intervals_of_the_episodes_it_names(said, count, episodes):
    """pretrained/README.md said that on seeds 3-5 alone belppo_quad's success interval on layout 3
    reached 96.6 %: that is the interval over all 384 episodes (378 of 384); the 192 of seeds 3-5
    alone (188 caught) give 94.8 %. Each quoted bound is the 95 % Wilson bound of the episodes named."""
    from pursuit_mj.stats import wilson_interval

    text = " ".join((ROOT / "pretrained" / "README.md").read_text().split())
    assert said in text
    lo, hi = (f"{100 * x:.1f}" for x in wilson_interval(count, episodes))
    assert lo in said, (said, lo, hi)
    if f"{lo}-" in said:  # a range: its upper bound too
        assert f"{lo}-{hi} %" in said, (said, lo, hi)


def test_docs_training_md_says_best_pt_ties_go_to_fewer_capture_steps_not_fewer_mean_steps():
    """training.md said best.pt's ties went 'to fewer steps', read beside the validation's
    mean_steps (a crash ends an episode early): the trainer breaks them by mean capture steps, a
    failure counting as max_steps (tests/test_train_checkpoint.py), and a full tie keeps the earlier."""
    text = " ".join((ROOT / "docs" / "training.md").read_text().split())
    said = text[text.index("`best.pt` (best validation success"):][:300]
    assert "ties to fewer capture steps" in said and "max_steps" in said and "earlier" in said, said


def test_adding_a_network_in_docs_training_md_states_how_a_trunk_is_called(monkeypatch):
    """The paragraph said a trunk 'maps observations (..., spec.dim) to features' but not that
    Actor and Critic call it as trunk(obs, spec): a trunk written to the words, forward(obs),
    stopped the first rollout in a TypeError ('takes 2 positional arguments but 3 were given').
    The call it names is the one the networks make, and the trunks it points to take it."""
    import dataclasses
    import inspect

    import torch

    from pursuit_mj.obs_spec import ObsSpec
    from train.config import NetConfig
    from train.networks import TRUNKS, Actor, Critic

    text = " ".join((ROOT / "docs" / "training.md").read_text().split("**Adding a network.**")[1].split("\n\n")[0].split())
    assert "`forward(obs, spec)`" in text, text
    for name, cls in TRUNKS.items():
        assert list(inspect.signature(cls.forward).parameters) == ["self", "obs", "spec"], name
    calls = []

    class Written(torch.nn.Module):  # a trunk written to the paragraph
        def __init__(self, spec, cfg):
            super().__init__()
            self.out_dim = 3

        def forward(self, obs, spec):
            calls.append(spec)
            return obs[..., :3]

    monkeypatch.setitem(TRUNKS, "written", Written)
    spec, cfg = ObsSpec.make(3, 1, 4), dataclasses.replace(NetConfig(), kind="written")
    obs = torch.zeros(5, 2, spec.dim)
    assert Actor(spec, cfg)(obs, spec)[0].shape == (5, 2, 2) and Critic(spec, cfg)(obs, spec).shape == (5, 2)
    assert calls == [spec, spec]


def test_docs_quote_the_heading_of_the_main_evaluation_table_as_eval_prints_it():
    """eval, demo and a study's table.txt print a heading above the main table naming the
    fidelity of its rows (evaluation.table_heading); docs/evaluation.md, which quotes the paired
    table's heading and pool's, said nothing of it, and docs/training.md called table.txt 'the
    table and the paired one'. Both now quote or name it, as the code prints it."""
    from pursuit_mj.env import EpisodeRecord
    from pursuit_mj.evaluation import summarise, table_heading

    records = [EpisodeRecord(0, 0, 0, "success", 100, None, {}, 1, "0")]
    rows = [summarise(policy, layout, "point", 0, records, 1000) for policy in ("heuristic", "a") for layout in "0123"]
    heading = table_heading(rows, "task hard with --set max_steps=500")
    assert heading == "evaluated 2 policies on 4 layouts, every row in point fidelity, task hard with --set max_steps=500"
    evaluation = " ".join((ROOT / "docs" / "evaluation.md").read_text().split())
    assert f"`{heading}`" in evaluation
    training = " ".join((ROOT / "docs" / "training.md").read_text().split())
    assert "`table.txt` (the table under a heading naming the fidelity and task" in training
