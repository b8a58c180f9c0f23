"""Every benchmark script ends in ``benchmarks/entry.py``: Ctrl-C, SIGTERM or SIGHUP give
one line and the signal's exit status, never a traceback, and a toolkit error one line."""

from __future__ import annotations

import ast
import errno
import json
import os
import signal
import subprocess
import sys

import pytest

from graphslam.pipelines.common import note_stop_signal
from slamcore.errors import GraphSlamError
from tests.benchmarks import BENCHMARKS, load_benchmark

#: Python files of benchmarks/ that are not scripts a user runs, or must stay bare.
NOT_SCRIPTS = {
    "plotting": "a helper module",
    "timing": "a helper module",
    "loop_real": "a helper module of bench_loop_pr.py",
    "entry": "the ending itself",
    "quiet_start": "the beginning itself",
    "bare_run": "the floor bench_command.py times: a bare gtsam script, nothing of ours",
}
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("*.py") if p.stem not in NOT_SCRIPTS)


def _main_block(path) -> str:
    tree = ast.parse(path.read_text())
    for node in tree.body:
        if isinstance(node, ast.If) and "__main__" in ast.unparse(node.test):
            return ast.unparse(node)
    return ""


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_script_ends_in_entry_run(name):
    """``entry.run``, by the module's name: ``from entry import run`` took the place of
    bench_mono_ekf.py's own run() (a TypeError from its first configuration)."""
    block = _main_block(BENCHMARKS / f"{name}.py")
    assert "import entry" in block and "raise SystemExit(entry.run(main))" in block, block
    assert "from entry import" not in (BENCHMARKS / f"{name}.py").read_text()


@pytest.fixture
def entry(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["bench_x.py"])
    return load_benchmark("entry")


def _handlers():
    return {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}


def test_status_and_handlers_pass_through(entry):
    before = _handlers()
    assert entry.run(lambda: None) == 0 and entry.run(lambda: 3) == 3
    assert _handlers() == before


def test_a_toolkit_error_is_one_line(entry, capsys):
    def main():
        raise GraphSlamError("data.txt:3: not a number\n  (second line)")

    assert entry.run(main) == entry.EXIT_ERROR
    assert capsys.readouterr().err == "bench_x.py: error: data.txt:3: not a number (second line)\n"


def test_a_signal_noted_by_a_runs_guard_is_named(entry, capsys):
    """A loop guard took SIGTERM and cut its run; whole() raised KeyboardInterrupt."""
    before = _handlers()

    def main():
        note_stop_signal(signal.SIGTERM)
        raise KeyboardInterrupt

    assert entry.run(main) == 143
    assert capsys.readouterr().err == "bench_x.py: interrupted (SIGTERM) before it finished\n"
    assert _handlers() == before


def test_a_script_that_went_on_after_a_signal_says_so(entry, capsys):
    def main():
        note_stop_signal(signal.SIGHUP)
        return 0

    assert entry.run(main) == 129
    err = capsys.readouterr().err
    assert err.startswith("bench_x.py: interrupted (SIGHUP) but a run took the signal") and err.count("\n") == 1


@pytest.mark.slow
@pytest.mark.parametrize("sig, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_to_a_running_benchmark_is_one_line(shared_data, tmp_path, sig, status):
    """bench_mrclam.py, stopped after its first run: the signal's status, one line, no
    traceback, no JSON."""
    out = tmp_path / "mrclam.json"
    cmd = [sys.executable, str(BENCHMARKS / "bench_mrclam.py"), "--data", str(shared_data / "mrclam6"),
           "--out", str(out)]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as proc:
        first = proc.stdout.readline()  # the first run is scored: the second one is running
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    assert first.startswith("robot 1"), first
    assert proc.returncode == status, err
    assert err == f"bench_mrclam.py: interrupted ({signal.Signals(sig).name}) before it finished\n"
    assert not out.exists()


@pytest.mark.parametrize("error, line", [
    (OSError(28, "No space left on device"), "no space left on device writing an output file: No space left on device"),
    (PermissionError(13, "Permission denied", "/ro/x.json"),
     "/ro/x.json cannot be written or replaced (Permission denied: another user's, or read-only)"),
    (IsADirectoryError(21, "Is a directory", "/tmp"), "/tmp is a folder; an output file of that name cannot be written"),
])
def test_an_output_the_disk_refuses_is_one_line(entry, capsys, error, line):
    def main():
        raise error

    assert entry.run(main) == entry.EXIT_ERROR
    assert capsys.readouterr().err == f"bench_x.py: error: {line}\n"


def test_another_os_error_keeps_its_traceback(entry):
    def main():
        raise ConnectionResetError(104, "Connection reset by peer")

    with pytest.raises(ConnectionResetError):
        entry.run(main)


def test_an_input_that_is_not_there_is_one_line(entry, capsys):
    def main():
        open("/nonexistent/lund_door/cameras.txt")

    assert entry.run(main) == entry.EXIT_ERROR
    assert capsys.readouterr().err == "bench_x.py: error: /nonexistent/lund_door/cameras.txt: No such file or directory\n"


def test_write_json_writes_what_json_dumps_would(entry, tmp_path):
    """The results keep their bytes: each script's indent, default= and trailing newline."""
    payload = {"rows": [{"ate_m": 0.25, "backend": "ekf"}], "data": tmp_path, "runs": 3}
    out = tmp_path / "x.json"
    for kwargs, newline in [({"indent": 1, "default": str}, False), ({"indent": 2, "default": str}, True)]:
        entry.write_json(out, payload, trailing_newline=newline, **kwargs)
        assert out.read_bytes() == (json.dumps(payload, **kwargs) + ("\n" if newline else "")).encode()
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]  # no temporary file left beside it


def _full_disk(monkeypatch, error: int) -> None:
    """Files opened by slamcore.files (atomic_open's temporary file) take half of a write,
    then fail with ``error`` as a full disk does."""
    import builtins

    from slamcore import files

    def full_open(path, mode="r", **kwargs):
        fh = builtins.open(path, mode, **kwargs)

        def write(text):
            type(fh).write(fh, text[: len(text) // 2])
            fh.flush()
            raise OSError(error, os.strerror(error))

        fh.write = write
        return fh

    monkeypatch.setattr(files, "open", full_open, raising=False)


@pytest.mark.parametrize("error, older", [(errno.ENOSPC, True), (errno.EDQUOT, False), (errno.EFBIG, True)])
def test_a_full_disk_prints_the_results_and_leaves_no_truncated_file(entry, tmp_path, capsys, monkeypatch,
                                                                      error, older):
    """A full disk at the end lost minutes of measurement and could leave half a JSON at
    --out, read later as a result: now the JSON is on stdout, the older file (or none) stays."""
    out = tmp_path / "x.json"
    if older:
        out.write_text('{"older": true}')
    payload = {"rows": [{"ate_m": 0.25}] * 20}
    _full_disk(monkeypatch, error)
    assert entry.run(lambda: entry.write_json(out, payload, indent=1)) == entry.EXIT_ERROR
    printed = capsys.readouterr()
    assert printed.out == json.dumps(payload, indent=1) + "\n"
    assert printed.err == (f"bench_x.py: error: {out}: {os.strerror(error)}; "
                           "the results are printed on stdout above\n")
    assert [p.name for p in tmp_path.iterdir()] == (["x.json"] if older else [])
    assert not older or out.read_text() == '{"older": true}'


def test_a_full_disk_under_stdout_too_is_said(entry, tmp_path, monkeypatch, capsys):
    """``bench_x.py > log`` on the same full disk: the JSON is lost, and the line says so."""
    class Full:
        def write(self, text):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def flush(self):
            pass

    _full_disk(monkeypatch, errno.ENOSPC)
    monkeypatch.setattr(sys, "stdout", Full())
    assert entry.run(lambda: entry.write_json(tmp_path / "x.json", {"rows": []})) == entry.EXIT_ERROR
    assert capsys.readouterr().err.endswith("the results could not be printed on stdout either\n")


def test_another_write_error_is_not_taken_for_a_full_disk(entry, tmp_path, capsys, monkeypatch):
    """An I/O error keeps its traceback, as before write_json; the older file stays."""
    out = tmp_path / "x.json"
    out.write_text("older")
    _full_disk(monkeypatch, errno.EIO)
    with pytest.raises(OSError) as e:
        entry.run(lambda: entry.write_json(out, {"rows": []}))
    assert e.value.errno == errno.EIO and capsys.readouterr().out == "" and out.read_text() == "older"


def test_a_benchmark_over_a_file_size_limit_prints_its_json(tmp_path):
    """bench_ekf_update.py --quick (about 2 s), its 4 kB JSON under a 1 kB file-size limit:
    the write fails with EFBIG as on a full disk, for real (temporary file, rename)."""
    import resource

    out = tmp_path / "ekf.json"
    out.write_text('{"older": true}\n')

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG from write(), not a kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (1024, 1024))

    cmd = [sys.executable, str(BENCHMARKS / "bench_ekf_update.py"), "--quick", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, preexec_fn=limit)
    assert done.returncode == 2, done.stderr
    assert done.stderr == (f"bench_ekf_update.py: error: {out}: {os.strerror(errno.EFBIG)}; "
                           "the results are printed on stdout above\n")
    printed = json.loads(done.stdout[done.stdout.index("\n{\n"):])  # after the printed table
    assert printed["benchmark"] == "ekf_update" and len(printed["results"]) == 2
    assert out.read_text() == '{"older": true}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["ekf.json"]  # no temporary file, no PNG


#: JSON writes in benchmarks/ that are no result at --out, by script and line start -> why
#: they stay plain writes.
NOT_RESULT_WRITES = {
    ("check_digests", "DIGESTS.write_text(json.dumps("):
        "--record rewrites benchmarks/digests.json, the repository's record (in git), not an --out",
    ("hostile_pass", '(path / "map.json").write_text(json.dumps('):
        "an attack's input: a saved map with its map.json edited",
    ("hostile_pass", '(folder / "earlier.json").write_text(json.dumps('):
        "the pass's note of an earlier run's bytes, in an attack's scratch folder",
    ("hostile_pass", '(m / "map.json").write_text(json.dumps('):
        "an attack's map.json edited by hand, in its scratch folder",
}
#: Scripts that write no JSON result -> what they write.
NO_JSON_RESULT = {
    "check_digests": "nothing at an --out (digests.json: NOT_RESULT_WRITES)",
    "table": "the README's targets table",
    "train_shipped_vocabulary": "the vocabulary .npz (VocabularyTree.save)",
}


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_script_writes_its_json_through_write_json(name):
    """A plain ``write_text(json.dumps(...))`` at the end lost the results on a full disk
    and could leave half a file at --out."""
    import re

    text = (BENCHMARKS / f"{name}.py").read_text()
    allowed = {start for script, start in NOT_RESULT_WRITES if script == name}
    plain = [line.strip() for line in text.splitlines()
             if re.search(r"json\.dump\(|\.write(_text)?\(json\.dumps\(", line)]
    assert [line for line in plain if not line.startswith(tuple(allowed))] == []
    assert all(any(line.startswith(start) for line in plain) for start in allowed), "a stale allow-list entry"
    assert name in NO_JSON_RESULT or "entry.write_json(" in text


@pytest.mark.parametrize("kind, good, bad", [
    ("count", [("1", 1), ("20", 20)], ["0", "-1", "1.5", "x"]),
    ("seed", [("0", 0), ("7", 7)], ["-1", "x"]),
    ("count_or_zero", [("0", 0), ("3", 3)], ["-1", "x"]),
    ("positive", [("7.5", 7.5), ("1e-3", 1e-3)], ["0", "-1", "nan", "inf", "x"]),
])
def test_numeric_options_refuse_what_would_fail_later(entry, kind, good, bad):
    """bench_active_search.py --pairs 0 ended in a ZeroDivisionError, --seed -1 in numpy's
    ValueError, bench_isam2_joint.py --repeats 0 in an empty median: now argparse's line."""
    import argparse

    parse = getattr(entry, kind)
    assert [parse(text) for text, _ in good] == [value for _, value in good]
    for text in bad:
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)


def test_lists_and_outputs_refuse_what_would_fail_later(entry, tmp_path):
    """Hostile pass 23: --seeds abc was a ValueError traceback, --backends abc a KeyError
    after the first back end's work, and --out x.png had the figure overwrite the JSON."""
    import argparse

    assert entry.int_list("0, 1,2") == [0, 1, 2]
    backends = entry.names_from("isam2", "ekf")
    assert backends("ekf,isam2") == ["ekf", "isam2"]
    for parse, text in ((entry.int_list, "abc"), (entry.int_list, "1,-2"), (backends, "isam2,ekf,"),
                        (backends, "abc"), (entry.output_file, str(tmp_path / "x.png"))):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)
    assert entry.output_file(str(tmp_path / "x.json")) == tmp_path / "x.json"


@pytest.mark.parametrize("script, argv, says", [
    ("bench_posegraph", ["{tmp}", "--out", "{tmp}/pg"], "no pose-graph files in"),
    ("bench_loop_pr", ["--kitti", "{tmp}/nowhere", "--out", "{tmp}/lp.json"], "no KITTI folder"),
    ("hostile_pass", ["--only", "no such attack", "--out", "{tmp}/h.json"], "no attack's name holds it"),
])
def test_arguments_that_select_nothing_are_refused_first(script, argv, says, tmp_path, capsys):
    """Each ran (a traceback after an empty folder was made, exit 0 with kitti07 null, a
    result of 0 attacks); now argparse's line before any work."""
    main = load_benchmark(script).main
    with pytest.raises(SystemExit) as e:
        main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    assert e.value.code == 2 and says in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, particles, steps", [
    (["--quick"], [10, 100], 20),
    (["--quick", "--particles", "5"], [5], 20),
    (["--quick", "--part", "5", "7"], [5, 7], 20),  # argparse's abbreviation
    (["--steps=7", "--quick"], [10, 100], 7),
])
def test_quick_sizes_leave_the_options_the_user_gave(entry, argv, particles, steps):
    """``--quick --particles 5`` ran bench_fastslam.py with 10 and 100 particles."""
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--particles", type=int, nargs="+", default=[10, 100, 1000])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    entry.quick_sizes(ap, argv, args, particles=[10, 100], steps=20)
    assert (args.particles, args.steps) == (particles, steps)


def test_every_quick_mode_sets_its_sizes_through_quick_sizes():
    """No script assigns an option under ``if args.quick:`` itself."""
    import re

    for path in sorted(BENCHMARKS.glob("*.py")):
        text = path.read_text()
        # an option read only when not --quick: --quick --seeds 3 ran seed 0 (pass 23: four
        # scripts, "[0] if args.quick else [int(s) for s in args.seeds...]" and the like)
        assert not re.search(r"if args\.quick else [^,)\n]*args\.", text), path.name
        assert not re.search(r"args\.quick or not args\.", text), path.name
        for block in re.findall(r"if args\.quick:\n((?:        .*\n)+)", path.read_text()):
            assert not re.search(r"^        (?:[a-z_]+, )*args\.[a-z_]+(?:, [a-z_.]+)* = ", block, re.M), (path.name, block)


def test_a_reader_that_leaves_costs_no_output(entry, tmp_path, monkeypatch):
    """``bench_fastslam.py | head -3`` ended in a BrokenPipeError traceback, its JSON not
    written: the rest of the printout now goes to /dev/null and the files are written."""
    import os

    r, w = os.pipe()
    os.close(r)  # the reader has left
    pipe = os.fdopen(w, "w", buffering=1)
    monkeypatch.setattr(sys, "stdout", pipe)
    out = tmp_path / "x.json"

    def main():
        for i in range(3):
            print(f"row {i}")
        out.write_text("{}")

    try:
        assert entry.run(main) == 0
    finally:
        pipe.close()
    assert out.read_text() == "{}" and sys.stdout is pipe


@pytest.mark.slow
def test_a_benchmark_piped_into_head_writes_its_json(shared_data, tmp_path):
    out = tmp_path / "mrclam.json"
    cmd = [sys.executable, str(BENCHMARKS / "bench_mrclam.py"), "--quick", "--data", str(shared_data / "mrclam6"),
           "--out", str(out)]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as proc:
        proc.stdout.readline()
        proc.stdout.close()  # as head does after its lines
        err = proc.stderr.read()
        proc.wait(timeout=120)
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert out.is_file() and out.with_suffix(".png").is_file()


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_output_option_is_checked_before_the_measurement(name):
    """``--out`` naming a folder, or a folder the user cannot write, was found when
    the results were written: one line, but after minutes of work, all of it lost."""
    import re

    for line in re.findall(r'add_argument\("--out",[^\n]*', (BENCHMARKS / f"{name}.py").read_text()):
        assert re.search(r"type=entry\.output_(file|folder)\b", line), (name, line)


def test_an_output_that_cannot_be_written_is_refused_by_argparse(entry, tmp_path):
    import argparse

    (tmp_path / "a_file").write_text("")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    assert entry.output_file(str(tmp_path / "new" / "x.json")) == tmp_path / "new" / "x.json"
    assert entry.output_folder(str(tmp_path / "runs")) == tmp_path / "runs"
    refusals = {
        entry.output_file: [(str(tmp_path), "is a folder; give a file name"),
                            (str(tmp_path / "a_file" / "x.json"), "a_file is an existing file, not a folder"),
                            (str(tmp_path / ("n" * 300) / "x.json"), "file systems take at most 255")],
        entry.output_folder: [(str(tmp_path / "a_file"), "is an existing file, not a folder")],
    }
    for check, cases in refusals.items():
        for text, reason in cases:
            with pytest.raises(argparse.ArgumentTypeError, match=reason) as e:
                check(text)
            assert not str(e.value).startswith(("--out", ":", " "))
    try:  # root writes anywhere: the permission case only where it holds
        (locked / "probe").write_text("")
    except PermissionError:
        with pytest.raises(argparse.ArgumentTypeError, match="cannot write in"):
            entry.output_file(str(locked / "x.json"))
    finally:
        locked.chmod(0o700)


def test_a_folder_as_out_stops_a_script_before_its_work(tmp_path):
    """One line from argparse and status 2, in the time it takes to import the script."""
    cmd = [sys.executable, str(BENCHMARKS / "bench_fastslam.py"), "--quick", "--out", str(tmp_path)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].endswith(f"argument --out: {tmp_path} is a folder; give a file name")
    assert done.stdout == ""


def _script_beside_quiet_start(tmp_path):
    import shutil

    shutil.copy(BENCHMARKS / "quiet_start.py", tmp_path / "quiet_start.py")
    script = tmp_path / "bench_x.py"
    script.write_text(
        "from __future__ import annotations\n\nimport quiet_start  # noqa: F401\n"
        "import os\nimport signal\nimport time\n\n"
        "os.kill(os.getpid(), signal.SIGINT)  # as a Ctrl-C while numpy loads\n"
        "time.sleep(5)\nprint('not reached')\n"
    )
    return script


def test_a_signal_while_a_script_starts_is_one_line(tmp_path):
    """The scripts import numpy, gtsam and the toolkit before entry.run installs its
    handlers: a Ctrl-C in that first second printed a KeyboardInterrupt traceback."""
    done = subprocess.run([sys.executable, str(_script_beside_quiet_start(tmp_path))],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 130
    assert done.stderr == "bench_x.py: interrupted (SIGINT) while starting\n"
    assert "not reached" not in done.stdout


def test_quiet_start_leaves_a_test_process_its_handlers():
    import signal

    before = signal.getsignal(signal.SIGINT)
    load_benchmark("quiet_start")
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_script_imports_quiet_start_first(name):
    source = (BENCHMARKS / f"{name}.py").read_text()
    imports = [ln for ln in source.splitlines() if ln.startswith(("import ", "from ")) and "__future__" not in ln]
    assert imports[0].startswith("import quiet_start"), name
