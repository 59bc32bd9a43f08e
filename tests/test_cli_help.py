"""Issue 27, items 3 and 4: help that matches the parser, and a closed pipe.

Every option a subcommand's ``--help`` names, and every option of a
cloudsieve command in README.md (its code blocks and its inline commands),
exists on that subcommand; an error of a subcommand prints that
subcommand's usage; help texts describe their flag; every command that
shows progress takes ``--no-progress`` (README says so). A command whose
stdout is closed (``| head -1``) ends with 0 and no traceback.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys

import pytest

from cloudsieve import params
from cloudsieve.cli import build_parser, main
from cloudsieve.cli._common import option_values
from conftest import ROOT, shared_file

PARSER = build_parser()
COMMANDS: dict[str, argparse.ArgumentParser] = next(
    a for a in PARSER._actions if isinstance(a, argparse._SubParsersAction)).choices
FLAG = re.compile(r"(?<![\w-])(--?[a-zA-Z][\w-]*)")


def flags_of(parser: argparse.ArgumentParser) -> set[str]:
    return set(parser._option_string_actions)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_a_help_names_exists(command):
    parser = COMMANDS[command]
    named = set(FLAG.findall(parser.format_help())) - {"-h"}
    missing = sorted(f for f in named if f not in flags_of(parser))
    assert missing == [], f"cloudsieve {command} --help names {missing}, which it does not take"


def test_the_top_level_help_names_only_its_own_options():
    assert set(FLAG.findall(PARSER.format_help())) <= flags_of(PARSER) | {"-vv"}  # -v twice


# ---------------------------------------------------------------- README


def _readme_commands() -> tuple[list[str], list[str]]:
    """The cloudsieve commands of README.md: (those of its code blocks, all: also inline `cloudsieve ...` or
    `SUBCOMMAND ...`), each without the program's name."""
    text = (ROOT / "README.md").read_text()
    start = r"(?:^|\s)(?:[\w./-]*/)?cloudsieve ((?:" + "|".join(COMMANDS) + r")\b.*)"
    blocks, spans = [], []
    for language, block in re.findall(r"```(\w*)\n(.*?)```", text, flags=re.S):
        for line in block.splitlines() if language in ("", "bash", "sh", "console") else ():
            for part in line.split("&&"):
                m = re.search(start, part.split(" #")[0])
                if m:
                    blocks.append(m.group(1).strip())
    for span in re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.S)):
        m = re.fullmatch(r"(?:\w+=\S* )*(?:cloudsieve )?((\w+)(?: .*)?)", span.strip())
        if m and m.group(2) in COMMANDS:
            spans.append(m.group(1))
    return sorted(set(blocks)), sorted(set(blocks + spans))


README_BLOCKS, README_COMMANDS = _readme_commands()


def test_readme_has_commands():
    assert len(README_BLOCKS) >= 10 and len(README_COMMANDS) > 20
    assert "demo" in README_BLOCKS and any(c.startswith("run ") for c in README_BLOCKS)


@pytest.mark.parametrize("line", README_COMMANDS)
def test_every_option_of_a_readme_command_exists(line):
    words = shlex.split(line)
    command = words[0]
    assert command in COMMANDS, line
    flags = [w.split("=")[0] for w in words[1:] if w.startswith("-")]
    missing = [f for f in flags if f not in flags_of(COMMANDS[command])]
    assert missing == [], f"README: `cloudsieve {line}` uses {missing}, which cloudsieve {command} does not take"


@pytest.mark.parametrize("line", README_BLOCKS)
def test_every_command_of_a_readme_code_block_is_accepted(line):
    """Each parses (SystemExit on an unknown option or a bad value) into its subcommand, each flag's value where
    the command reads it, and its options pass the checks its API runs first (params.validate)."""
    words = shlex.split(line)
    args = PARSER.parse_args(words)
    command = COMMANDS[words[0]]
    assert args.func.__module__ == f"cloudsieve.cli.{words[0]}"
    for i, word in enumerate(words):
        flag, _, inline = word.partition("=")
        action = command._option_string_actions.get(flag)
        if action is None:
            continue
        if action.nargs == 0:  # store_true / store_false
            assert getattr(args, action.dest) is action.const, flag
        else:
            text = inline or words[i + 1]
            value = action.type(text) if action.type else text
            got = getattr(args, action.dest)
            assert value in got if isinstance(action, argparse._AppendAction) else got == value, flag
    if words[0] in params.COMMANDS:
        params.validate(words[0], option_values(args, words[0]))


@pytest.mark.parametrize("command", ["simplify", "ingest", "export", "evaluate", "compare", "run", "demo"])
def test_every_command_with_progress_takes_no_progress(command):
    assert "--no-progress" in flags_of(COMMANDS[command])


def test_run_no_progress_runs_without_progress_lines(tmp_path):
    import json

    p = tmp_path / "p.json"
    p.write_text(json.dumps({"scheduler": "sync", "pipeline": [
        {"type": "readers.las", "filename": str(shared_file("simple.las"))},
        {"type": "writers.las", "filename": str(tmp_path / "out.laz")}]}))
    proc = cloudsieve(["run", p, "--no-progress"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "cloudsieve.progress" not in proc.stderr and (tmp_path / "out.laz").is_file()
    proc = cloudsieve(["run", p, "--set", "writers.las.overwrite=true"], tmp_path)
    assert proc.returncode == 0 and "INFO cloudsieve.progress: pipeline: 1,065 points in" in proc.stderr


# ---------------------------------------------------------------- errors and texts


@pytest.mark.parametrize("argv,usage,message", [
    (["demo", "--count", "5"], "usage: cloudsieve demo ", "cloudsieve demo: error: unrecognized arguments: --count 5"),
    (["demo", "--threshold", "0.1"], "usage: cloudsieve demo ",
     "cloudsieve demo: error: unrecognized arguments: --threshold 0.1"),
    (["run", "p.json", "--bogus"], "usage: cloudsieve run ", "cloudsieve run: error: unrecognized arguments: --bogus"),
    (["info", "a.las", "extra"], "usage: cloudsieve info ", "cloudsieve info: error: unrecognized arguments: extra"),
])
def test_an_error_of_a_subcommand_prints_its_usage(capsys, argv, usage, message):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(usage) and err.rstrip().endswith(message)


def _help_of(command: str, flag: str) -> str:
    action = COMMANDS[command]._option_string_actions[flag]
    return action.help


def test_help_describes_the_flag_not_the_default():
    assert _help_of("evaluate", "--no-surface") == ("point level only: skip the surface level (ball-pivoting meshes, "
                                                    "Metro distances, compactness)")
    assert _help_of("evaluate", "--no-strict") == _help_of("evaluate", "--force") == (
        "compare clouds of different CRS or units, with a warning (default: refuse them)")
    assert _help_of("ingest", "--overwrite") == _help_of("export", "--overwrite") == _help_of(
        "simplify", "--overwrite") == ("replace what is at the destination (DST, or ingest's STORE); simplify also "
                                       "discards a work store left by another source or other options")


def test_simplify_help_opens_with_what_the_default_rule_does():
    first = COMMANDS["simplify"].description.split(". ")[0]
    assert "entropy" not in first and "KM" not in first and "FCM" not in first
    assert COMMANDS["simplify"].description.index("eliminate") < COMMANDS["simplify"].description.index("K-means")


# ---------------------------------------------------------------- a closed pipe


def cloudsieve(argv, cwd, stdout=subprocess.PIPE):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "cloudsieve", *map(str, argv)], stdout=stdout,
                          stderr=subprocess.PIPE, text=True, env=env, cwd=cwd)


def closed_pipe(argv, cwd):
    """Run with stdout a pipe whose reader is already gone (as after ``| head -1``): (exit code, stderr)."""
    r, w = os.pipe()
    os.close(r)
    try:
        proc = cloudsieve(argv, cwd, stdout=w)
    finally:
        os.close(w)
    return proc.returncode, proc.stderr


@pytest.mark.parametrize("argv", [
    ["info", "{las}"], ["info", "{las}", "--json"], ["simplify", "--help"], ["--help"],
    ["simplify", "{las}", "{tmp}/o.las", "--ratio", "0.5", "--scheduler", "sync", "--no-progress"],
    ["simplify", "{las}", "{tmp}/j.las", "--ratio", "0.5", "--scheduler", "sync", "--no-progress", "--json"],
    ["evaluate", "{las}", "{las}", "--no-surface", "--no-progress"],
], ids=["info", "info-json", "simplify-help", "help", "simplify", "simplify-json", "evaluate"])
def test_a_closed_stdout_ends_quietly(tmp_path, argv):
    argv = [a.format(las=shared_file("simple.las"), tmp=tmp_path) for a in argv]
    code, err = closed_pipe(argv, tmp_path)
    assert (code, err) == (0, "")
