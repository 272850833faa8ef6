"""The simulator-core commands: `pursuit-mj simulate` (the interim main job) and `pursuit-mj bench`."""

from __future__ import annotations

import numpy as np
import pytest

from pursuit_cli import build_parser, main
from pursuit_cli.bench import targets
from pursuit_cli.simulate import circle_commands, fly
from pursuit_mj.config import default_config
from pursuit_mj.layout import load_layout


def test_simulate_prints_a_row_per_layout_and_fidelity(capsys):
    assert main(["simulate", "--seconds", "0.3", "--layout", "3"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("cluttered")]
    assert [r.split()[1] for r in rows] == ["quadrotor", "point"]
    assert out.count("final xy (m): pursuer_0") == 2 and "total wall time" in out
    assert "0.3 s (3 decision steps) per run" in out and [r.split()[2] for r in rows] == ["0.3", "0.3"]


def test_simulate_refuses_a_missing_layout_before_printing_its_table(tmp_path, capsys):
    assert main(["simulate", "-i", str(tmp_path / "none.yaml")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "none.yaml': no such file" in err


def test_simulate_refuses_a_spawn_region_too_small_for_the_team_before_printing_its_table(tmp_path, capsys):
    """It printed the table's header, then the error."""
    small = tmp_path / "small.yaml"
    small.write_text("name: small\narena: {width: 3.6, height: 5.0}\n"
                     "spawn:\n  pursuers: {x: [0.2, 0.3], y: [0.2, 0.3]}\n  evaders: {x: [0.2, 3.4], y: [4.2, 4.8]}\n")
    assert main(["simulate", "-i", str(small)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert f"the spawn region of {small} (x=[0.2, 0.3], y=[0.2, 0.3]) cannot reliably hold 3 pursuers 0.35 m apart" in captured.err


def test_simulate_flies_every_team_its_spawn_check_accepts(capsys):
    """The check before the table drew spawns as the env does (200 tries a draw), the flight
    with one greedy try: 16 pursuers passed the check, printed the header, then were refused
    ('the pursuers spawn region has no room for 16 drones 0.35 m apart')."""
    assert main(["simulate", "--seconds", "0.2", "--layout", "0", "--fidelity", "point", "--pursuers", "16"]) == 0
    out = capsys.readouterr().out
    assert "16 pursuers + 1 evader fly" in out and "pursuer_15 (" in out


def test_simulate_flies_only_the_layout_and_fidelity_chosen_through_set(capsys):
    assert main(["simulate", "--seconds", "0.2", "--set", "fidelity=point", "--set", "layout=1"]) == 0
    rows = [line.split()[:2] for line in capsys.readouterr().out.splitlines() if line.split()[:1] in (["open"], ["walls"], ["bars"], ["cluttered"])]
    assert rows == [["walls", "point"]]


def test_simulate_flies_only_what_a_task_file_names_even_at_its_default(tmp_path, capsys):
    task = tmp_path / "t.yaml"
    task.write_text("fidelity: quadrotor\nlayout: 0\n")  # both the defaults, but named
    assert main(["simulate", "--seconds", "0.2", "--task", str(task)]) == 0
    rows = [line.split()[:2] for line in capsys.readouterr().out.splitlines() if line.split()[:1] in (["open"], ["walls"], ["bars"], ["cluttered"])]
    assert rows == [["open", "quadrotor"]]


def test_scripted_flight_in_an_open_arena_is_clean_and_ends_circling_the_middle():
    config = default_config(random_obstacles=0)
    report = fly(config, load_layout(0), seconds=6.0)
    assert report.contact_steps.sum() == 0
    assert report.max_altitude_error < 0.03 and np.degrees(report.max_tilt) < 20
    radius = np.hypot(*(report.final_xy - [1.8, 2.5]).T)
    assert ((radius > 0.3) & (radius < 1.6)).all(), radius  # they started 1.7 m or more away
    assert report.real_time_factor > 1.0


@pytest.mark.parametrize("team, arena", [((6, 3), (3.6, 5.0)), ((1, 1), (1.2, 1.6))])
def test_scripted_circles_fit_inside_the_border_for_any_team_and_arena(tmp_path, team, arena):
    """The radii were 0.5 m + 0.3 m per drone whatever the arena: a 6 + 3 team in the 3.6 m wide
    open arena, or 1 + 1 in a 1.2 x 1.6 m one, flew circles beyond the border and pressed against
    it, reported as hundreds of contact steps of a flight that should touch nothing."""
    width, height = arena
    path = tmp_path / "arena.yaml"
    path.write_text(f"name: a\narena: {{width: {width}, height: {height}}}\n"
                    f"spawn:\n  pursuers: {{x: [0.2, {width - 0.2}], y: [0.2, 0.4]}}\n"
                    f"  evaders: {{x: [0.2, {width - 0.2}], y: [{height - 0.4}, {height - 0.2}]}}\n")
    config = default_config(random_obstacles=0, fidelity="point", n_pursuers=team[0], n_evaders=team[1])
    report = fly(config, load_layout(str(path)), seconds=20.0)
    assert report.contact_steps.sum() == 0, dict(zip(report.names, report.contact_steps))
    gap = np.minimum(np.minimum(report.final_xy[:, 0], width - report.final_xy[:, 0]),
                     np.minimum(report.final_xy[:, 1], height - report.final_xy[:, 1]))
    assert (gap > 0.1).all(), report.final_xy


def test_circle_commands_point_inward_far_away_and_along_the_circle_on_it():
    center = np.array([0.0, 0.0])
    xy = np.array([[[10.0, 0.0], [1.0, 0.0]]])
    v = circle_commands(xy, center, np.array([1.0, 1.0]), np.array([0.3, 0.6]))
    assert v[0, 0, 0] < -0.25  # mostly toward the centre
    np.testing.assert_allclose(v[0, 1], [0.0, 0.6], atol=1e-12)  # tangential, counter-clockwise
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), [[0.3, 0.6]])


def test_bench_targets_are_found_as_modules_with_the_documented_interface():
    found = targets()
    assert "physics" in found
    for module in found.values():
        assert isinstance(module.HELP, str) and callable(module.add_arguments) and callable(module.run)
    help_text = build_parser().format_help()
    assert "bench" in help_text and "simulate" in help_text and "layout" in help_text


def test_bench_physics_prints_the_table(capsys):
    assert main(["bench", "physics", "--worlds", "2", "--seconds", "0.1", "--fidelity", "point"]) == 0
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("fidelity"))
    assert "raw phys steps/s" in header and "ours/raw" in header and "peak RSS MiB" in header
    row = next(line for line in out.splitlines() if line.startswith("point "))
    cells = row.split()
    assert cells[1] == "2" and float(cells[6]) > 0 and float(cells[7]) > 0 and float(cells[8]) > 10


@pytest.mark.parametrize(
    "argv, message",
    [
        (["simulate", "--seconds", "0"], "--seconds: must be > 0"),
        (["simulate", "--layout", "8"], "flag --layout 8: key 'layout': 8 is not a built-in layout index (0-3)"),
        # named all three flags typed, though only --delta-t is wrong
        (["simulate", "-i", "0", "--fidelity", "point", "--delta-t", "0.002"],
         "error: flag --delta-t 0.002: control_dt 0.002 is not a whole number of controller periods"),
        (["simulate", "--set", "n_pursuers=40"], "key 'n_pursuers': 40 is out of range"),
        (["simulate", "--layout", "3", "--set", "random_obstacles=40", "--seconds", "0.3"], "lower the task's random_obstacles (now 40)"),
        (["bench", "physics", "--worlds", "0"], "--worlds: world counts must be >= 1, got 0"),
        (["bench", "physics", "--seconds", "-1"], "--seconds: must be > 0"),
        (["bench", "physics", "--nthread", "-1"], "--nthread: must be in 0..256, got -1"),
        (["bench", "physics", "--nthread", "3000000000"], "--nthread: must be in 0..256, got 3000000000"),  # a TypeError traceback
        (["bench", "physics", "--worlds", "4", "3000000000"], "--worlds: world counts must be at most 4096, got 3000000000"),  # hung
        (["bench", "env", "--worlds", "5000"], "--worlds: world counts must be at most 4096, got 5000"),
        # silently stepped the one layout of --set layout instead
        (["bench", "physics", "--set", "random_layout=true"], "--set random_layout=true: this benchmark steps one layout"),
        # a huge finite value used to overflow the step or block count into an OverflowError traceback
        (["simulate", "--seconds", "0.05"], "--seconds: 0.05 is shorter than one decision step (control_dt 0.1 s)"),  # flew 0.1 s
        (["simulate", "--seconds", "1e308"], "--seconds: must be at most 86400 (a simulated day per run), got 1e+308"),
        (["bench", "physics", "--seconds", "1e308"], "--seconds: must be at most 3600 (an hour per configuration)"),
        (["bench", "env", "--seconds", "1e308"], "--seconds: must be at most 3600 (an hour per configuration)"),
        # a count of episodes no machine plays: it sat silently listing seeds
        (["eval", "--episodes", "100000000000"], "--episodes: expected an integer in 1..1,000,000, got 100000000000"),
        (["demo", "--episodes", "2000000"], "--episodes: expected an integer in 1..1,000,000, got 2000000"),
        (["study", "--budget-minutes", "1", "--episodes", "2000000", "--out", "{tmp}/s"], "--episodes: expected an integer in 1..1,000,000"),
        # a budget whose seconds overflow: the study probed, then ended in an OverflowError traceback
        (["study", "--budget-minutes", "1e308", "--out", "{tmp}/s"], "--budget-minutes: must be at most 525600 (a year), got 1e+308"),
        # a folder where a file is meant: it said 'no such file'
        (["config", "-i", "{tmp}"], "layout '{tmp}': a folder, not a layout file"),
        (["config", "-ec", "{tmp}"], "{tmp}: a folder, not a task file"),
        (["fly", "check", "--flight", "{tmp}"], "{tmp}: a folder, not a flight file"),
        # flags that did nothing, without a word
        (["eval", "--rerun-episodes", "5"], "--rerun-episodes 5: records nothing without --rerun FILE.rrd"),
        (["plot", "--eval", "e.json", "--metric", "success"], "--metric success: chooses what training logs (--log) are drawn by"),
        # a task value the heuristic team cannot work with: it did not say which flag or file gave it
        (["eval", "--policy", "heuristic", "--set", "n_rays=4"], "--set n_rays=4: the heuristic team sees walls only through"),
        (["eval", "--policy", "heuristic", "-ec", "{tmp}/rays.yaml"], "task file {tmp}/rays.yaml: n_rays 4: the heuristic team"),
        # the folder of --out is a file: it named --csv, which was not given
        (["eval", "--out", "{tmp}/rays.yaml/t"], "--out {tmp}/rays.yaml/t path {tmp}/rays.yaml/t.csv: {tmp}/rays.yaml exists and is not a folder"),
    ],
)
def test_bad_input_exits_2_with_one_line(argv, message, capsys, tmp_path):
    argv, message = [a.replace("{tmp}", str(tmp_path)) for a in argv], message.replace("{tmp}", str(tmp_path))
    (tmp_path / "rays.yaml").write_text("n_rays: 4\n")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


def test_negative_numbers_in_scientific_notation_reach_the_flags_own_check(capsys):
    assert main(["simulate", "--seconds", "-2.5e-1"]) == 2
    assert "--seconds: must be > 0, got -0.25" in capsys.readouterr().err
    for text in ("-inf", "nan"):
        with pytest.raises(SystemExit):
            main(["simulate", "--seconds", text])
        assert f"argument --seconds: expected a finite number, got '{text}'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["study", "--budget-minutes", "nan"])  # nan <= 0 is False: it used to start a study
    assert "expected a finite number" in capsys.readouterr().err


def test_negative_numbers_in_scientific_notation_count_among_a_flags_several_values(tmp_path, capsys):
    # argparse read -1e-1 as an unknown flag: a valid yaw was refused ("unrecognized arguments: -1e-1"),
    # and gluing it to the flag (--center=-1e5) left a two-value flag one value short
    out = tmp_path / "yawed.yaml"
    assert main(["layout", "new", str(out), "--box", "1", "2", "0.2", "0.2", "-1e-1"]) == 0
    assert load_layout(out).obstacles[0].yaw == -0.1
    assert main(["layout", "new", str(tmp_path / "c.yaml"), "--border", "circle", "--center", "-1e5", "2"]) == 2
    assert "centre [-100000.0, 2.0]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["layout", "new", str(tmp_path / "b.yaml"), "--box", "1", "2", "0.2", "0.2", "-inf"])
    assert "argument --box: expected a finite number, got '-inf'" in capsys.readouterr().err


def test_the_simulator_package_imports_neither_train_nor_torch_nor_the_command_line():
    # DESIGN.md section 4: pursuit_mj never imports train/; the command line (pursuit_cli)
    # is the one package that imports both. Every module is imported with those blocked.
    import subprocess
    import sys

    script = """
import importlib, pkgutil, sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('torch', 'train', 'pursuit_cli'):
            raise ImportError('blocked ' + name)
sys.meta_path.insert(0, Block())
import pursuit_mj
bad = []
for m in pkgutil.walk_packages(pursuit_mj.__path__, 'pursuit_mj.'):
    try:
        importlib.import_module(m.name)
    except ImportError as exc:
        bad.append(f'{m.name}: {exc}')
print('\\n'.join(bad) or 'ok')
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "ok", out.stdout + out.stderr


def test_python_dash_m_pursuit_cli_is_the_pursuit_mj_command():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "pursuit_cli", "layout", "check", "7"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and out.stderr.startswith("pursuit-mj layout check: error: layout 7"), out.stderr


_BROKEN_PIPE_COMMAND = """
import os, subprocess, sys
import pursuit_cli, pursuit_cli.config_cmd as command
def run(args):
    if sys.argv[1] == "print":  # `pursuit-mj ... | head`: print into a reader that has gone
        while True:
            print("a line of the table")
    if sys.argv[1] == "os.write":  # the same below Python's buffer (nothing left to flush)
        while True:
            os.write(sys.stdout.fileno(), b"a line of the table\\n" * 1000)
    print("the table so far", flush=True)  # another pipe breaks while standard output is read
    encoder = subprocess.Popen([sys.executable, "-c", "pass"], stdin=subprocess.PIPE)
    encoder.wait()
    encoder.stdin.write(b"a frame" * 200_000)
    encoder.stdin.flush()
command.run = run
sys.exit(pursuit_cli.main(["config"]))
"""


@pytest.mark.parametrize("mode", ["print", "os.write"])
def test_output_piped_into_head_ends_quietly_and_successfully(mode):
    import subprocess
    import sys

    cli = subprocess.Popen([sys.executable, "-c", _BROKEN_PIPE_COMMAND, mode], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE)
    assert cli.stdout.readline().startswith(b"a line")
    cli.stdout.close()  # head has the lines it wanted
    _, err = cli.communicate(timeout=120)
    assert (cli.returncode, err) == (0, b"")


def test_a_broken_pipe_other_than_the_output_is_an_error_naming_where_it_broke():
    """An encoder (ffmpeg) or a link that ends early is a failure, not `| head`: it exited 0."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _BROKEN_PIPE_COMMAND, "encoder"], capture_output=True, text=True,
                         timeout=120)
    assert out.stdout == "the table so far\n"
    assert out.returncode == 1, out.stderr
    assert out.stderr.startswith("pursuit-mj config: error: [Errno 32] Broken pipe in <string>:"), out.stderr
    assert ", run (a pipe or socket other than the standard output closed" in out.stderr


@pytest.mark.parametrize("sig, said, code", [("SIGTERM", "interrupted by SIGTERM\n", 143), ("SIGINT", "interrupted\n", 130)])
@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_a_stop_signal_that_a_library_call_reports_as_its_own_error_still_ends_as_an_interrupt(monkeypatch, capsys, sig, said, code):
    """A SIGTERM (or Ctrl-C) landing while mujoco's bindings convert an argument came out as their
    TypeError ('incompatible function arguments'): a traceback and exit code 1 instead of 130."""
    import os
    import signal

    import mujoco

    import pursuit_cli.config_cmd as config_cmd

    class StopWhileConverted:  # the signal arrives while the binding reads this sequence
        def __len__(self):
            return 2

        def __getitem__(self, i):
            if i == 0:
                os.kill(os.getpid(), getattr(signal, sig))
            if i >= 2:
                raise IndexError(i)
            return 1.0

    def build_a_scene(args):
        mujoco.MjSpec().add_material().texrepeat = StopWhileConverted()
        return 0

    monkeypatch.setattr(config_cmd, "run", build_a_scene)
    assert main(["config"]) == code  # 128 + the signal's number, as a shell reports a process a signal ended
    assert capsys.readouterr().err.endswith(f"pursuit-mj config: {said}")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers given back


@pytest.mark.parametrize("phase", ["build_parser", "mujoco_import_error"])
@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_ctrl_c_while_the_command_starts_up_is_one_line_not_a_traceback(monkeypatch, capsys, phase):
    """Ctrl-C while the subcommands' modules (numpy, torch ...) or mujoco import: it printed a traceback."""
    import os
    import signal

    import pursuit_cli

    original = getattr(pursuit_cli, phase)

    def interrupted_on_the_way(*args):
        os.kill(os.getpid(), signal.SIGINT)
        return original(*args)

    monkeypatch.setattr(pursuit_cli, phase, interrupted_on_the_way)
    assert main(["config"]) == 130
    assert capsys.readouterr().err == "pursuit-mj: interrupted while starting\n"


@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_ctrl_c_that_mujocos_start_up_reports_as_an_import_error_is_an_interrupt(monkeypatch, capsys):
    """Seen with a real Ctrl-C 0.1 s after start: mujoco's import failed with 'ImportError:
    initialization failed', and the command blamed MUJOCO_GL."""
    import builtins
    import os
    import signal

    real_import = builtins.__import__

    def import_cut_short(name, *args, **kwargs):
        if name == "mujoco":  # its C start-up turns the interrupt into a failed initialisation
            try:
                os.kill(os.getpid(), signal.SIGINT)
            except KeyboardInterrupt:
                raise ImportError("initialization failed") from None
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", import_cut_short)
    assert main(["config"]) == 130
    assert capsys.readouterr().err == "pursuit-mj: interrupted while starting\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers given back


def test_version_names_the_package_commit_and_the_libraries_that_decide_results(capsys):
    import subprocess

    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    first, second = capsys.readouterr().out.splitlines()
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert first.startswith("pursuit-mj 0.1.0 (") and (not head or f"git {head[:10]}" in first), first
    assert second.startswith("python 3.11") and "mujoco 4.0.0" in second and "torch 2.13.0" in second, second


def test_an_error_quotes_a_long_bad_value_in_part(tmp_path, capsys):
    """A layout file that is one long line of text was echoed whole into the error."""
    bad = tmp_path / "notes.yaml"
    bad.write_text("just some notes " * 200 + "\n")
    assert main(["config", "-i", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{bad}: expected a mapping, got 'just some notes" in err and "... (3201 characters)" in err and len(err) < 300, err


@pytest.mark.parametrize("argv, message", [
    (["plot", "-o", "", "--eval", "e.json"], "argument -o/--out: an empty path ('')"),  # plotted into the current folder
    (["render", "-s", " "], "argument -s/--save-path: an empty path (' ')"),
    (["layout", "show", "0", "-o", ""], "argument -o/--out: an empty path"),
    (["fly", "--flight", "example", "--virtual", "--policy", "heuristic", "--events", ""], "argument --events: an empty path"),
])
def test_an_empty_output_path_is_a_usage_error_not_the_current_folder(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and message in err, err


def test_a_file_written_again_removes_what_a_killed_write_of_it_left_and_nothing_else(tmp_path):
    """kill -9 during an eval or render left `.NAME.*.part*` (as large as the file) for good."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from pursuit_mj.io_utils import atomic_write_text

    target = tmp_path / "v.mp4"
    cut_short = ("import os, sys; from pursuit_mj.io_utils import atomic_path\n"
                 "with atomic_path(sys.argv[1]) as tmp:\n    tmp.write_bytes(b'half a video'); os._exit(9)")
    for name in ("v.mp4", "other.mp4"):
        subprocess.run([sys.executable, "-c", cut_short, str(tmp_path / name)], check=False,
                       cwd=Path(__file__).resolve().parents[1])
    (left,) = tmp_path.glob(".v.mp4.*.part.mp4")
    (other,) = tmp_path.glob(".other.mp4.*.part.mp4")
    in_progress = tmp_path / f".v.mp4.{os.getppid()}-abcd1234.part.mp4"  # a live process's write
    in_progress.write_bytes(b"being written")
    atomic_write_text(target, "done")
    assert target.read_text() == "done"
    assert not left.exists() and other.exists() and in_progress.exists()


@pytest.mark.parametrize("command", ["render", "eval"])
def test_a_render_or_eval_sweeps_its_folder_of_what_killed_writes_of_other_names_left(tmp_path, capsys, command, monkeypatch):
    """A killed render's `.NAME.PID-*.part.mp4` stayed until that very file was written again, and a
    render's file name holds its seed and a digest of its settings, so that was mostly never."""
    import os
    import subprocess
    import sys
    import time

    dead_pid = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True, check=True).stdout.strip()
    out = tmp_path / "out"
    out.mkdir()
    old_dead = out / f".x_seed3_ab12.mp4.{dead_pid}-abcd1234.part.mp4"
    young_dead = out / f".y.mp4.{dead_pid}-abcd1234.part.mp4"  # perhaps a writer on another machine: too young
    old_alive = out / f".z.mp4.{os.getppid()}-abcd1234.part.mp4"  # a live process's write
    not_ours = out / ".notes.txt"
    for path in (old_dead, young_dead, old_alive, not_ours):
        path.write_bytes(b"half a file")
    linked = out / f".w.mp4.{dead_pid}-abcd1234.part.mp4"  # a link of that shape is no file atomic_path made
    linked.symlink_to(not_ours)
    an_hour_ago = time.time() - 3600
    for path in (old_dead, old_alive, not_ours):
        os.utime(path, (an_hour_ago, an_hour_ago))
    os.utime(linked, (an_hour_ago, an_hour_ago), follow_symlinks=False)
    if command == "render":
        argv = ["render", "--fidelity", "point", "--set", "max_steps=5", "--width", "64", "--height", "48", "--no-video",
                "--final-frame", "-s", f"{out}/"]
    else:
        monkeypatch.chdir(tmp_path)  # the folder is named as given (it was named resolved, --plots as given)
        argv = ["eval", "--fidelity", "point", "--episodes", "1", "--set", "max_steps=5", "--layouts", "0", "-q",
                "--out", "out/t"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    flag = "-s" if command == "render" else "--out"
    assert f"note: {flag}: removed 1 temporary file of writes cut short" in err and old_dead.name in err, err
    if command == "eval":
        assert f"in out: {old_dead.name}" in err, err
    assert not old_dead.exists() and young_dead.exists() and old_alive.exists() and not_ours.exists() and linked.is_symlink()


def test_a_ctrl_c_while_the_command_line_process_exits_prints_no_traceback():
    """Ctrl-C pressed again while Python ran its exit handlers (torch's, after a run had been
    stopped and saved) printed 'Exception ignored in atexit callback ... KeyboardInterrupt'."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import atexit, os, signal, sys, time\n"
            "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(0.2)))\n"
            "sys.argv = ['pursuit-mj', 'config', '--set', 'max_steps=5']\n"
            "from pursuit_cli import main\n"
            "sys.exit(main())\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0 and "max_steps: 5" in proc.stdout
    assert "KeyboardInterrupt" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr


def test_simulate_notes_the_task_keys_a_scripted_flight_does_not_use(capsys):
    """--perception-radius, --observability or --set random_layout=true were taken without a word,
    though nothing in a scripted flight perceives or draws a layout."""
    assert main(["simulate", "--seconds", "0.1", "--layout", "0", "--fidelity", "point", "--perception-radius", "1.0",
                 "--set", "random_layout=true"]) == 0
    err = capsys.readouterr().err
    assert "note: perception_radius, random_layout play no part in simulate" in err, err
    assert main(["simulate", "--seconds", "0.1", "--layout", "0", "--fidelity", "point"]) == 0
    assert "play no part" not in capsys.readouterr().err


def test_no_new_empty_folders_removes_only_the_empty_folders_a_failure_made(tmp_path):
    """The shared rule of a command refused or failed after it made its output folders: a folder
    on the way to an output that was not there before and is empty goes, innermost first (a/b/new
    takes a/b and a with it); one that holds anything stays, with the folders above it; a folder
    that was there stays even when empty; nothing is removed when the body succeeds."""
    from pursuit_mj.io_utils import check_writable_folder, no_new_empty_folders

    (tmp_path / "there").mkdir()
    deep, kept_file, there = tmp_path / "a" / "b" / "new", tmp_path / "k" / "log" / "x.jsonl", tmp_path / "there" / "n"
    with pytest.raises(KeyboardInterrupt):
        with no_new_empty_folders():
            for folder in (deep, kept_file.parent, there):
                check_writable_folder(folder, "--out")
            kept_file.write_text("{}\n")  # what the command wrote before it failed
            raise KeyboardInterrupt
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == [
        "k", "k/log", "k/log/x.jsonl", "there"]
    with no_new_empty_folders():
        check_writable_folder(deep, "--out")
    assert deep.is_dir()


@pytest.mark.parametrize("command", [["eval", "--episodes", "1"], ["demo", "--episodes", "1"], ["study", "--budget-minutes", "1"],
                                     ["layout", "new", "x.yaml", "--border", "polygon"]])
def test_a_list_flag_given_twice_keeps_both_lists_not_only_the_last(command):
    """`eval --layouts 0 --layouts 1` played layout 1 alone, without a word (argparse keeps the last
    list), while --policy and --model, given twice, both count; likewise --points of layout new."""
    parser = build_parser()
    flag, first, second = ("--points", ["0,0", "4,0"], ["4,4", "0,4"]) if command[0] == "layout" else ("--layouts", ["0"], ["1", "3"])
    args = parser.parse_args([*command, flag, *first, flag, *second])
    assert getattr(args, flag.lstrip("-")) == first + second
    if command[0] == "study":
        assert parser.parse_args(command).layouts == ["0", "1", "2", "3"]  # the default stays when none is given


def test_obstacle_kinds_given_twice_keep_both_and_the_default_is_both_kinds():
    parser = build_parser()
    assert parser.parse_args(["layout", "new", "x.yaml"]).obstacle_kinds == ["box", "cylinder"]
    args = parser.parse_args(["layout", "new", "x.yaml", "--obstacle-kinds", "box", "--obstacle-kinds", "cylinder"])
    assert args.obstacle_kinds == ["box", "cylinder"]



def test_a_negative_corner_of_points_reaches_the_layout_check_not_argparse(tmp_path, capsys):
    """--points -1,0 ... was taken for an unknown flag: 'argument --points: expected at least one
    argument', about a flag that was given three corners."""
    assert main(["layout", "new", str(tmp_path / "p.yaml"), "--border", "polygon", "--points", "-1,0", "3,0", "3,4"]) == 2
    err = capsys.readouterr().err
    assert "expected at least one argument" not in err and "[-1.0, 0.0]" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("value, advice", [("osmesa", "set MUJOCO_GL to egl if it is installed, or unset it"),
                                           ("egl", "set MUJOCO_GL to osmesa if it is installed, or unset it"),
                                           ("foo", "set MUJOCO_GL to egl or osmesa (whichever is installed), or unset it")])
def test_a_mujoco_gl_that_breaks_mujoco_is_not_advised_again(value, advice, monkeypatch):
    """MUJOCO_GL=osmesa without OSMesa installed: 'set MUJOCO_GL to egl or osmesa (whichever is
    installed)', the value that had just failed among the advice."""
    import sys

    from pursuit_cli import mujoco_import_error

    monkeypatch.setenv("MUJOCO_GL", value)
    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` fails, as a missing GL library makes it
    said = mujoco_import_error()
    assert said.startswith(f"environment variable MUJOCO_GL='{value}': mujoco cannot start with it") and said.endswith(advice), said


@pytest.mark.parametrize("argv", [
    ["eval", "--shield", "--episodes", "1", "--fidelity", "point"],
    ["eval", "--shield", "--policy", "heuristic", "--episodes", "1", "--fidelity", "point"],
    ["render", "--shield", "--policy", "heuristic", "--fidelity", "point", "-s", "{tmp}/r/"],
    ["fly", "--flight", "example", "--policy", "heuristic", "--shield", "--virtual", "--events", "{tmp}/e.jsonl"],
])
def test_a_shield_that_would_change_nothing_is_refused(argv, tmp_path, capsys):
    """eval --shield with the heuristic team alone (which has the shield built in) ran the same
    table as without it, without a word: a user believed a shielded run had been made."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--shield: heuristic has the shield built in, so --shield changes nothing" in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []
    assert main(["eval", "--shield", "--policy", "heuristic", "--policy", "random", "--episodes", "1", "--worlds", "1",
                 "--fidelity", "point", "--set", "max_steps=2", "-q"]) == 0  # one policy it shields: run
    assert "random+shield" in capsys.readouterr().out


@pytest.mark.parametrize("argv, said", [
    (["render", "-m", "a.pt", "-m", "b.pt"], "argument -m/--model: given twice (a.pt, then b.pt); render plays one policy"),
    (["render", "--policy", "heuristic", "--policy", "random"],
     "argument --policy: given twice (heuristic, then random); render plays one policy"),
    (["fly", "--flight", "example", "--model", "a.pt", "--model", "b.pt"],
     "argument --model: given twice (a.pt, then b.pt); fly flies one policy"),
    (["fly", "--flight", "example", "--policy", "heuristic", "--policy", "random"],
     "argument --policy: given twice (heuristic, then random); fly flies one policy"),
    (["demo", "-m", "a.pt", "--model", "b.pt"], "argument -m/--model: given twice (a.pt, then b.pt); demo shows one model"),
])
def test_one_policy_flag_given_twice_is_refused_where_the_command_plays_one(argv, said, capsys):
    """render -m a.pt -m b.pt (eval takes several --model, each a row) rendered b.pt alone,
    without a word about a.pt."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err


def test_no_new_empty_folders_keeps_a_folder_another_process_made_meanwhile(tmp_path):
    """A folder missing when a command started but made by another process while it ran (two evals
    started together into a new shared/ folder) is that process's: the command refused afterwards
    removed it while it was still empty, and the other's output had nowhere to go."""
    from pursuit_mj.io_utils import check_writable, no_new_empty_folders

    shared = tmp_path / "shared"
    with pytest.raises(ValueError):
        with no_new_empty_folders():
            shared.mkdir()  # the other process, between this one's start and its refusal
            check_writable(shared / "a.csv", "--csv")
            raise ValueError("refused")
    assert shared.is_dir()


def test_no_new_empty_folders_removes_what_it_made_where_it_made_it_after_a_chdir(tmp_path, monkeypatch):
    """The folders a failed command made are removed where they were made, even if the current
    folder changed meanwhile: the relative name then named another folder, a user's empty one."""
    from pursuit_mj.io_utils import check_writable_folder, no_new_empty_folders

    start, other = tmp_path / "start", tmp_path / "other"
    (other / "n1" / "x").mkdir(parents=True)  # the user's, empty
    start.mkdir()
    monkeypatch.chdir(start)
    with pytest.raises(KeyboardInterrupt):
        with no_new_empty_folders():
            check_writable_folder("n1/x", "--plots n1/x")
            monkeypatch.chdir(other)
            raise KeyboardInterrupt
    assert list(start.iterdir()) == []
    assert (other / "n1" / "x").is_dir()


def test_no_new_empty_folders_nested_hands_its_folders_to_the_outer_one(tmp_path):
    """A study makes each arm's run folder within the trainer's no_new_empty_folders, inside its own:
    a folder the inner one made and kept (it succeeded) is removed by the outer one that fails later."""
    from pursuit_mj.io_utils import check_writable_folder, no_new_empty_folders

    with pytest.raises(KeyboardInterrupt):
        with no_new_empty_folders():
            check_writable_folder(tmp_path / "out", "--out")
            with no_new_empty_folders():
                check_writable_folder(tmp_path / "out" / "runs" / "a", "run folder")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_a_folder_under_a_file_is_refused_as_not_a_directory(tmp_path):
    """mkdir -p's own reason: a folder asked under a file is 'Not a directory' (make_folders said
    'File exists', of the file above it)."""
    from pursuit_mj.io_utils import check_writable_folder

    (tmp_path / "mine.txt").write_text("mine")
    with pytest.raises(ValueError, match=r"cannot create the folder .*mine.txt/sub/x \(Not a directory\)"):
        check_writable_folder(tmp_path / "mine.txt" / "sub" / "x", "--plots")


def test_an_atomic_write_to_a_named_pipe_or_device_writes_into_it_and_leaves_it_in_place(tmp_path):
    """eval --json /dev/null (or fly align --write /dev/null, any table or copy written atomically)
    wrote a temporary file beside it and renamed it over the device: run as root, /dev/null became
    a regular file holding the table, for every program on the machine. A character device or a
    named pipe is now written in place; here a named pipe stands for /dev/null."""
    import os
    import stat
    import threading

    from pursuit_mj.io_utils import atomic_write_text

    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(pipe.read_text()), daemon=True)
    reader.start()
    atomic_write_text(pipe, "policy,layout\n")
    reader.join(5)
    assert stat.S_ISFIFO(os.stat(pipe).st_mode), "the pipe was replaced by a file"
    assert got == ["policy,layout\n"] and [p.name for p in tmp_path.iterdir()] == ["pipe"]


@pytest.mark.parametrize("argv", [["pool", "{long}.json", "t1.json"], ["eval", "--policy", "{long}.py:Team", "--episodes", "1"]])
def test_a_file_name_too_long_for_the_file_system_is_one_line_naming_it(argv, capsys):
    """pool and --policy with a 300-byte file name ended in an OSError traceback from os.stat deep inside
    (ENAMETOOLONG): a name the user typed, told as one line that shows it."""
    long = "a" * 300
    assert main([a.replace("{long}", long) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "File name too long" in err and long in err and len(err.strip().splitlines()) == 1, err


def _fake_dev_with_stdout_to_a_file(tmp_path, monkeypatch):
    """A stand-in for /dev whose 'stdout' leads to a regular file, as /dev/stdout does when the
    shell redirects the output to a file (the real /dev is never touched)."""
    import os

    from pursuit_mj import io_utils

    dev = tmp_path / "dev"
    dev.mkdir()
    out = tmp_path / "out.json"
    out.write_text("")
    os.symlink(out, dev / "stdout")
    monkeypatch.setattr(io_utils, "DEVICES_FOLDER", str(dev))
    return dev, out


def test_an_atomic_write_to_dev_stdout_redirected_to_a_file_is_refused_and_leaves_dev_alone(tmp_path, monkeypatch):
    """'eval --json /dev/stdout > out.json' run as root wrote a temporary file in /dev and renamed it
    over /dev/stdout: the link became a regular file among the devices (for every program on the
    machine) and out.json stayed empty. A name in /dev that is no device or pipe is now refused."""
    import os

    from pursuit_mj.io_utils import atomic_write_text

    dev, out = _fake_dev_with_stdout_to_a_file(tmp_path, monkeypatch)
    with pytest.raises(ValueError, match=r"stdout: a name in .*dev, the folder of devices, that leads to a regular file"):
        atomic_write_text(dev / "stdout", '{"a": 1}')
    assert os.path.islink(dev / "stdout") and out.read_text() == ""
    assert sorted(p.name for p in dev.iterdir()) == ["stdout"]  # no temporary file left there either
    with pytest.raises(ValueError, match=r"new.json: a name in .*dev, the folder of devices, that is not there"):
        atomic_write_text(dev / "new.json", "{}")
    assert sorted(p.name for p in dev.iterdir()) == ["stdout"]


def test_an_output_path_in_dev_that_is_no_device_is_refused_before_any_work(tmp_path, monkeypatch):
    from pursuit_mj.io_utils import check_writable

    dev, _ = _fake_dev_with_stdout_to_a_file(tmp_path, monkeypatch)
    with pytest.raises(ValueError, match=r"^--json path .*stdout: a name in .*dev, the folder of devices, that leads to a regular file"):
        check_writable(str(dev / "stdout"), "--json")
    with pytest.raises(ValueError, match=r"^--rerun path .*x.rrd: a name in .*dev, the folder of devices, that is not there"):
        check_writable(str(dev / "x.rrd"), "--rerun")
    check_writable(str(dev / "stdout"), "--events", appended=True)  # appended to, the file it leads to takes it
    with pytest.raises(ValueError, match=r"^--events path .*new.log: a name in .*dev, the folder of devices, that is not there"):
        check_writable(str(dev / "new.log"), "--events", appended=True)
    check_writable(str(tmp_path / "out.json"), "--json")  # elsewhere, as before


def test_the_package_boundaries_hold_in_the_source_not_only_at_import_time():
    """DESIGN.md section 4, read in the source, so that a lazy import inside a function (which
    importing every module does not run) is caught too: pursuit_mj names neither train nor
    pursuit_cli in any import, and train takes from pursuit_mj only public names of its modules
    (no leading underscore in the module path or the name imported)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent

    def imports(package):
        for path in sorted((root / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    yield path, node.lineno, [a.name for a in node.names], []
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    yield path, node.lineno, [node.module], [a.name for a in node.names]

    crossing = [f"{p.relative_to(root)}:{line} imports {m}" for p, line, modules, _ in imports("pursuit_mj")
                for m in modules if m.split(".")[0] in ("train", "pursuit_cli")]
    assert not crossing, crossing
    private = [f"{p.relative_to(root)}:{line} takes {'.'.join([modules[0], *names])}" for p, line, modules, names in imports("train")
               if modules[0].split(".")[0] == "pursuit_mj"
               and any(part.startswith("_") for part in modules[0].split(".")[1:] + names)]
    assert not private, private


@pytest.mark.parametrize("argv, advice", [
    (["render", "--shield", "--fidelity", "point", "-s", "{tmp}/r/"],
     "leave it out, or give the policy to shield with --model or --policy (render plays one policy)"),
    (["fly", "--flight", "example", "--policy", "heuristic", "--shield", "--virtual", "--events", "{tmp}/e.jsonl"],
     "leave it out, or give the policy to shield with --model or --policy (fly flies one policy)"),
    (["eval", "--shield", "--policy", "heuristic", "--episodes", "1", "--fidelity", "point"],
     "leave it out (it shields the other --model and --policy given)"),
])
def test_a_shield_refused_for_changing_nothing_gives_advice_for_the_command(argv, advice, tmp_path, capsys):
    """render and fly, which play one policy, said eval's advice: 'leave it out (it shields the other
    --model and --policy given)', of other policies they do not take; 'render --shield' alone (the
    heuristic team by default) named a policy the user never gave, with no word of how to shield one."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.strip().endswith("--shield: heuristic has the shield built in, so --shield changes nothing; " + advice), err
    assert len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("argv, said", [
    (["render", "--policy", "random", "--layouts", "2"],
     "pursuit-mj render: error: unrecognized arguments: --layouts 2; did you mean --layout? (see pursuit-mj render --help)"),
    (["eval", "--policy", "heuristic", "--episods", "3"], "pursuit-mj eval: error: unrecognized arguments: --episods 3; did you mean --episodes?"),
    (["eval", "--policy", "heuristic", "stray"], "pursuit-mj eval: error: unrecognized arguments: stray (see pursuit-mj eval --help)"),
])
def test_an_unknown_flag_is_refused_by_its_command_naming_the_closest_flag_it_has(capsys, argv, said):
    """'render --layouts 2' (eval's spelling; render plays one layout) was refused as 'pursuit-mj:
    error: unrecognized arguments: --layouts 2 (see pursuit-mj --help)', naming neither the command
    whose flags to look up nor the flag meant."""
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and said in err and len(err.splitlines()) == 1, err


def test_an_unknown_flag_of_a_subcommand_action_is_refused_by_that_action(capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["layout", "show", "0", "--sed", "3"])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and err.startswith("pursuit-mj layout show: error: unrecognized arguments: --sed 3; did you mean --seed?"), err


@pytest.mark.parametrize("argv, said", [
    (["train", "--config", "classic", "--pursuers", "2"],
     "pursuit-mj train: error: unrecognized arguments: --pursuers 2; --pursuers is a task flag, which train does not "
     "take: --set task.n_pursuers=VALUE (see pursuit-mj train --help)"),
    (["bench", "train", "-ev", "0.5"],
     "pursuit-mj bench train: error: unrecognized arguments: -ev 0.5; -ev is a task flag, which bench train does not "
     "take: --set task.evader_speed=VALUE"),
    (["bench", "physics", "--observability", "full"],
     "pursuit-mj bench physics: error: unrecognized arguments: --observability full; --observability is a task flag, "
     "which bench physics does not take: --set observability=VALUE"),
    (["bench", "render", "--delta_t", "0.05"],
     "pursuit-mj bench render: error: unrecognized arguments: --delta_t 0.05; --delta_t is a task flag, which bench "
     "render does not take"),
])
def test_a_task_flag_given_to_a_command_without_it_is_refused_naming_the_key_to_set(capsys, argv, said):
    """'train --pursuers 2' was refused with '; did you mean --resume?': train sets task keys by
    --set task.KEY, and the closest of its own flags is no help."""
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and said in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("argv, said", [
    (["fly", "--flight", "example", "--policy", "heuristic", "--virtual", "--wind", "2"],
     "pursuit-mj fly: error: unrecognized arguments: --wind 2 (see pursuit-mj fly --help)"),
    (["fly", "--flight", "example", "--virtual", "--polcy", "heuristic"],
     "pursuit-mj fly: error: unrecognized arguments: --polcy heuristic; did you mean --policy?"),
    (["fly", "--flight", "example", "--pursuers", "2"],
     "pursuit-mj fly: error: unrecognized arguments: --pursuers 2; --pursuers is a task flag, which fly does not take: "
     "--set n_pursuers=VALUE"),
])
def test_an_unknown_flag_of_fly_is_refused_naming_it_not_its_value_as_an_action(capsys, argv, said):
    """fly has the optional actions check and align: the value of an unknown flag ('--speed 2') was
    taken for the action and refused as "argument [check | align]: invalid choice: '2'", naming
    neither the flag nor what was meant."""
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and said in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("argv, said", [
    (["--layout", "2", "eval"], "pursuit-mj: error: unrecognized arguments: --layout 2; give flags after the command "
                                "(pursuit-mj COMMAND --layout ...)"),
    (["bench", "--worlds", "4", "env"], "pursuit-mj bench: error: unrecognized arguments: --worlds 4; give flags after "
                                        "the command (pursuit-mj bench COMMAND --worlds ...)"),
])
def test_a_flag_given_before_the_command_is_refused_saying_where_it_goes(capsys, argv, said):
    """'pursuit-mj --layout 2 eval' read as a task flag pursuit-mj does not take (or, before that,
    as the command '2'): the flag is eval's, given too early."""
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and said in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("argv, said", [
    (["--foo", "eval"], "pursuit-mj: error: unrecognized arguments: --foo; give flags after the command (pursuit-mj COMMAND --foo ...)"),
    (["--ot=x", "eval"], "pursuit-mj: error: unrecognized arguments: --ot=x; give flags after the command"),
    (["bench", "--foo", "env"], "pursuit-mj bench: error: unrecognized arguments: --foo; give flags after the command "
                                "(pursuit-mj bench COMMAND --foo ...)"),
])
def test_an_unknown_flag_before_the_command_is_refused_by_the_parser_it_was_given_to(capsys, argv, said):
    """'pursuit-mj --foo eval' was refused as eval's ('pursuit-mj eval: error: ... did you mean
    --out?'): the unknown flags were looked up in the innermost command chosen, wherever they stood."""
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and said in err and len(err.splitlines()) == 1, err


def test_fly_still_refuses_an_unknown_action_as_one():
    parser = build_parser()
    with pytest.raises(SystemExit) as stopped:
        parser.parse_known_args(["fly", "chek", "--flight", "example"])
    assert stopped.value.code == 2


@pytest.mark.parametrize("before", [["--virt"], ["--foo=1"]])
def test_an_action_after_a_flag_that_takes_no_next_value_is_refused_as_the_action(capsys, before):
    """An unknown value right after a flag is taken for that flag's value only where the flag is one
    fly does not know and could take it: '--virt' is argparse's abbreviation of --virtual (which fly
    takes), '--foo=1' has its value. 'fly ... --virt chek' was refused as
    'unrecognized arguments: --virt chek; did you mean --virtual?', a flag that was taken."""
    with pytest.raises(SystemExit) as stopped:
        main(["fly", "--flight", "example", *before, "chek"])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and "invalid choice: 'chek'" in err and len(err.splitlines()) == 1, err


@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_a_stop_within_stops_held_waits_for_the_block_and_then_interrupts():
    import signal

    from pursuit_mj.io_utils import stops_held

    done = []
    with pytest.raises(KeyboardInterrupt):
        with stops_held():
            signal.raise_signal(signal.SIGINT)
            done.append("after the stop")  # the block goes on to its end
    assert done == ["after the stop"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is back
    with stops_held():  # nothing held: nothing raised
        done.append("quiet")
    assert done[-1] == "quiet"



@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_a_stop_held_while_the_block_fails_is_delivered_with_the_failure_as_its_cause():
    """A block under stops_held that failed (a file it could not write) while a stop was held
    ended in the stop's KeyboardInterrupt alone, the failure only its implicit context, and the CLI
    told 'interrupted' without it. The stop is still delivered (it is not lost to a caller that
    catches the failure), and the failure is now its cause, which pursuit_cli.main prints."""
    import signal

    from pursuit_mj.io_utils import stops_held

    failure = ValueError("out/ep0.png: cannot write it")
    with pytest.raises(KeyboardInterrupt) as stopped:
        with stops_held():
            signal.raise_signal(signal.SIGINT)
            raise failure
    assert stopped.value.__cause__ is failure
    with pytest.raises(ValueError) as failed:  # no stop held: the failure as it is
        with stops_held():
            raise failure
    assert failed.value is failure and failed.value.__cause__ is None

#: a module run as `python -m` (as `python -m pursuit_cli` is): argv[1] says where a Ctrl-C lands
_STOPPED_PROCESS = """
import argparse, signal, sys
import pursuit_cli, pursuit_cli.config_cmd as config_cmd
how, run_dir = sys.argv[1], sys.argv[2]
sys.argv = ["pursuit-mj", "train", "--resume", run_dir] if how == "resume" else ["pursuit-mj", "config"]

def ctrl_c():
    signal.raise_signal(signal.SIGINT)  # handled at once, as a Ctrl-C arriving here

def run(args):
    if how == "in_generated_code":  # as in the code dataclasses and namedtuple generate (exec, eval) as modules import
        exec("ctrl_c()")
    else:
        ctrl_c()
    return 0

config_cmd.run = run
if how == "resume":  # the trainer's start-up, stopped inside such code
    from train.trainer import Trainer
    Trainer.resume = lambda *a, **k: exec("ctrl_c()")
if how == "between_start_up_and_command":
    parse = argparse.ArgumentParser.parse_known_args
    def parse_after_ctrl_c(self, *a, **k):
        ctrl_c()
        return parse(self, *a, **k)
    argparse.ArgumentParser.parse_known_args = parse_after_ctrl_c
if how == "again_while_saying_so":
    said = pursuit_cli._interrupted
    def and_again(*a):
        code = said(*a)
        ctrl_c()  # a second Ctrl-C right after the line
        return code
    pursuit_cli._interrupted = and_again
sys.exit(pursuit_cli.main())
"""


@pytest.mark.parametrize("how, said", [
    ("in_generated_code", "pursuit-mj config: interrupted\n"),
    ("resume", "pursuit-mj train: interrupted\n"),
    ("between_start_up_and_command", "pursuit-mj: interrupted while starting\n"),
    ("again_while_saying_so", "pursuit-mj config: interrupted\n"),
])
def test_a_ctrl_c_anywhere_ends_the_process_with_130_and_one_line_never_by_sigint(tmp_path, how, said):
    """Seen as `python -m pursuit_cli train --resume` stopped while it started: 'interrupted'
    printed, and yet the process died by SIGINT (-2 to a Python caller). A KeyboardInterrupt that
    leaves code run by exec() or eval() of a string marks it unhandled for good (CPython 3.11),
    even once caught, and a process run with -m then ends by SIGINT, whatever its exit code. A
    Ctrl-C while the arguments were parsed escaped as a traceback; so did a second one while
    'interrupted' was printed."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from conftest import stop_signals_at_their_defaults

    (tmp_path / "stopped_cli.py").write_text(_STOPPED_PROCESS)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "last.pt").write_bytes(b"")  # resume is stopped before it reads it
    repo = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(repo)])}
    out = subprocess.run([sys.executable, "-m", "stopped_cli", how, str(tmp_path / "run")], capture_output=True,
                         text=True, timeout=120, env=env, cwd=tmp_path, preexec_fn=stop_signals_at_their_defaults)
    assert (out.returncode, out.stderr) == (130, said)



#: run as `python -m`: the arguments are parsed right after an interrupt inside generated code (exec) that
#: start-up caught; argv[1] says whether it was a Ctrl-C (the CLI's handler ran) or a KeyboardInterrupt raised
#: by code. (Right before the parse: any later exec or eval, as of a dataclass, would clear the mark itself.)
_START_UP_INTERRUPTED = """
import argparse, signal, sys
import pursuit_cli
how, sys.argv = sys.argv[1], ["pursuit-mj", *sys.argv[2:]]
parse = argparse.ArgumentParser.parse_known_args

def parse_after_an_interrupt(self, *a, **k):
    try:  # as a library's start-up that catches what reaches it, in code made with exec or eval
        exec("signal.raise_signal(signal.SIGINT)" if how == "ctrl_c" else "raise KeyboardInterrupt")
    except KeyboardInterrupt:
        pass
    return parse(self, *a, **k)

argparse.ArgumentParser.parse_known_args = parse_after_an_interrupt
sys.exit(pursuit_cli.main())
"""


@pytest.mark.parametrize("how, argv, code, said", [
    ("raised", ["config", "--no-such-flag"], 2, "pursuit-mj config: error: unrecognized arguments: --no-such-flag "
                                                "(see pursuit-mj config --help)"),
    ("raised", ["config", "--help"], 0, ""),
    ("ctrl_c", ["config", "--no-such-flag"], 130, "pursuit-mj: interrupted while starting"),
    ("ctrl_c", ["config", "--help"], 130, "pursuit-mj: interrupted while starting"),
])
def test_an_interrupt_caught_at_start_up_before_argparse_exits_ends_with_the_code_meant(tmp_path, how, argv, code, said):
    """A KeyboardInterrupt that passed through code run by exec() leaves CPython 3.11's 'unhandled
    interrupt' mark, which main cleared only once the command returned: when argparse then exited
    (a bad flag: 2, --help: 0), its SystemExit went past that, and a `python -m` process died by
    SIGINT (-2). Now argparse's code stands when no stop came (a KeyboardInterrupt raised by code,
    caught); when a Ctrl-C came (the CLI's handler ran, and start-up swallowed its interrupt), the
    command was asked to stop while it started: 'interrupted while starting' and 130, as a Ctrl-C
    anywhere else in start-up ends it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from conftest import stop_signals_at_their_defaults

    (tmp_path / "started_cli.py").write_text(_START_UP_INTERRUPTED)
    repo = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(repo)])}
    out = subprocess.run([sys.executable, "-m", "started_cli", how, *argv], capture_output=True, text=True, timeout=120,
                         env=env, cwd=tmp_path, preexec_fn=stop_signals_at_their_defaults)
    assert out.returncode == code, (out.returncode, out.stderr[-2000:])
    assert out.stderr.splitlines()[-1:] == ([said] if said else []), out.stderr
    if argv[-1] == "--help" and how == "raised":
        assert out.stdout.startswith("usage: pursuit-mj config")


@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_a_ctrl_c_taken_at_start_up_stops_a_bare_pursuit_mj_too(monkeypatch, capsys):
    """A Ctrl-C that start-up's imports took for their own error stops the command once the
    arguments are read, and a stop followed by --help or a usage error ends it so (130). A bare
    `pursuit-mj` (no command: the help and 2, a usage error) skipped that check: it printed the help
    and exited 2, the stop lost. It now ends as the others: the help, then 'interrupted while
    starting' and 130."""
    import signal

    import pursuit_cli

    build = pursuit_cli.build_parser

    def build_taking_a_ctrl_c():  # as an import that catches what reaches it while the commands load
        parser = build()
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass
        return parser

    monkeypatch.setattr(pursuit_cli, "build_parser", build_taking_a_ctrl_c)
    assert main([]) == 130
    err = capsys.readouterr().err
    assert err.startswith("usage: pursuit-mj") and err.endswith("\npursuit-mj: interrupted while starting\n"), err
    monkeypatch.setattr(pursuit_cli, "build_parser", build)  # without a stop: the help and 2, as before
    assert main([]) == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: pursuit-mj") and "interrupted" not in err


def _stop_landing_once_at(monkeypatch, when, stop):
    """Patch signal.signal so that right after the call `when(sig, handler)` picks, the signal
    `stop` arrives (its handler runs at once, as Python runs a handler at the next bytecode)."""
    import signal

    real, fired = signal.signal, []

    def landing(sig, handler):
        previous = real(sig, handler)
        if not fired and when(sig, handler):
            fired.append(sig)
            signal.raise_signal(stop)
        return previous

    monkeypatch.setattr(signal, "signal", landing)
    return fired


@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
@pytest.mark.parametrize("landing", ["while_giving_back", "while_taking"])
def test_stops_held_gives_every_handler_back_when_a_stop_lands_while_it_swaps_them(monkeypatch, landing):
    """stops_held swaps the stop handlers one by one, and Python runs a handler at the next bytecode.
    A Ctrl-C right after it gave SIGINT's handler back (raising there) left SIGTERM and SIGHUP on the
    block's holder for good: every later kill was appended to a list no one reads. A kill right
    after it took SIGINT, before it took SIGTERM, left SIGINT on the holder: every later Ctrl-C was
    swallowed. Every handler is back either way, and the stop still raises."""
    import signal

    from pursuit_mj.io_utils import stops_held

    def term(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    if landing == "while_giving_back":  # SIGINT's default handler reinstalled, then Ctrl-C
        when, stop = (lambda sig, handler: handler is signal.default_int_handler), signal.SIGINT
    else:  # SIGINT taken, then a kill
        when, stop = (lambda sig, handler: sig == signal.SIGINT), signal.SIGTERM
    before = {s: signal.signal(s, term) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        fired = _stop_landing_once_at(monkeypatch, when, stop)
        with pytest.raises(KeyboardInterrupt):
            with stops_held():
                if landing == "while_taking":
                    pytest.fail("the block ran although a stop came before it began")
        monkeypatch.undo()
        assert fired == [signal.SIGINT]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) is term and signal.getsignal(signal.SIGHUP) is term
    finally:
        monkeypatch.undo()
        for s, h in before.items():
            signal.signal(s, h)


@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
def test_a_stop_landing_as_stops_held_gives_its_handlers_back_keeps_the_blocks_failure_as_its_cause(monkeypatch):
    """A stop held while the block failed is raised with the failure as its cause, which
    pursuit_cli.main prints before 'interrupted'. A Ctrl-C landing right after stops_held gave
    SIGINT's handler back (the block had failed) raised there with no cause: the failure, a file
    that could not be written and what was in place, was not told. It is the cause there too."""
    import signal

    from pursuit_mj.io_utils import stops_held

    failure = ValueError("out/ep0.png: cannot write it")
    fired = _stop_landing_once_at(monkeypatch, lambda sig, handler: handler is signal.default_int_handler, signal.SIGINT)
    with pytest.raises(KeyboardInterrupt) as stopped:
        with stops_held():
            raise failure
    monkeypatch.undo()
    assert fired == [signal.SIGINT] and stopped.value.__cause__ is failure
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.usefixtures("ctrl_c_as_in_a_terminal")
@pytest.mark.parametrize("landing", ["while_taking", "while_giving_back"])
def test_termination_as_interrupt_gives_every_handler_back_when_a_ctrl_c_lands_meanwhile(monkeypatch, landing):
    """A Ctrl-C that landed while termination_as_interrupt took or gave back its handlers (one by
    one; Python runs a handler at the next bytecode) raised there and left SIGTERM and SIGHUP on
    the command's handler after it: a Python caller's later SIGTERM raised KeyboardInterrupt
    instead of ending the process."""
    import signal

    from pursuit_cli import termination_as_interrupt

    before = {s: signal.signal(s, signal.SIG_DFL) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        if landing == "while_taking":  # SIGTERM taken, SIGINT not yet
            when = lambda sig, handler: sig == signal.SIGTERM and callable(handler)  # noqa: E731
        else:  # SIGTERM given back, SIGINT not yet
            when = lambda sig, handler: sig == signal.SIGTERM and handler == signal.SIG_DFL  # noqa: E731
        fired = _stop_landing_once_at(monkeypatch, when, signal.SIGINT)
        with pytest.raises(KeyboardInterrupt):
            with termination_as_interrupt():
                pass
        monkeypatch.undo()
        assert fired == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL and signal.getsignal(signal.SIGHUP) == signal.SIG_DFL
    finally:
        monkeypatch.undo()
        for s, h in before.items():
            signal.signal(s, h)
