"""The command line's conventions (scripts/cli.py): defaults in every --help at every level,
--version, a sub-command's own usage on its own errors, one address syntax with one-line
errors (`watch --connect tcp:HOST:PORT`), train --quick and the short-budget warning."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
from pathlib import Path

import pytest

from skyherd.scripts.cli import DefaultsFormatter, build_parser, main

ROOT = Path(__file__).resolve().parents[2]


def _walk(parser: argparse.ArgumentParser, name: str = "skyherd"):
    yield name, parser
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for n, sp in a.choices.items():
                yield from _walk(sp, f"{name} {n}")


def test_every_option_of_every_sub_command_shows_its_default():
    parsers = list(_walk(build_parser(None)))
    assert {"skyherd watch", "skyherd train ab", "skyherd train irl", "skyherd fly"} <= {
        n for n, _ in parsers
    }
    missing = []
    for name, p in parsers:
        assert p.formatter_class is DefaultsFormatter, name
        text = p.format_help()  # formats every action: a bad %(default) would raise here
        f = p._get_formatter()
        for a in p._actions:
            empty = isinstance(a.default, list | tuple | str) and not a.default
            if (
                not a.option_strings
                or a.default in (None, argparse.SUPPRESS)
                or a.nargs == 0
                or empty
            ):
                continue
            if not re.search(r"default:? \S", f._expand_help(a)):
                missing.append(f"{name} {a.option_strings[0]}")
        assert text
    assert missing == []
    fly = dict(_walk(build_parser("fly")))["skyherd fly"].format_help()
    assert re.search(r"--duration.*\n?.*default", fly)
    ab = " ".join(dict(_walk(build_parser("train")))["skyherd train ab"].format_help().split())
    assert "(default: 15000)" in ab and "(default: 0.97)" in ab


def test_version_names_the_package_and_the_commit(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    head = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True
    ).stdout
    out = capsys.readouterr().out
    assert out.startswith("skyherd 0.1.0 (git ") and head[:12] in out


@pytest.mark.parametrize(
    "argv, usage",
    [
        (["watch", "--frmes", "3"], "usage: skyherd watch "),
        (["train", "ab", "--dqn-stpes", "3"], "usage: skyherd train ab "),
        (["train", "irl", "--seeds", "x"], "usage: skyherd train irl "),
    ],
)
def test_an_error_in_a_sub_command_prints_its_own_usage(argv, usage, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.startswith(usage) and "usage: skyherd [-h]" not in err


def test_watch_takes_the_pymavlink_address_form_walltime(tmp_path, capsys):
    """`--connect tcp:127.0.0.1:1` (nothing there) waits 0.3 s of wall time and fails cleanly."""
    code = main(["watch", "--connect", "tcp:127.0.0.1:1", "--timeout", "0.3", "--no-show",
                 "--runs-dir", str(tmp_path)])  # fmt: skip
    err = capsys.readouterr()
    assert code == 1 and "Json5Err" not in err.err + err.out and "cargo" not in err.err + err.out
    (run,) = list(tmp_path.iterdir())
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["zenoh"]["connect"] == ["tcp/127.0.0.1:1"]
    assert (
        "**Ended: failed**: no frame on skyherd/uav0/camera/frame"
        in (run / "summary.md").read_text()
    )


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--connect", "tcp:127.0.0.1"], "--connect 'tcp:127.0.0.1' needs HOST:PORT"),
        (["--connect", "tcp:127.0.0.1:99999"], "port must be 1..65535"),
        (["--zenoh-config", "BAD"], "cannot open a Zenoh session (--zenoh-config"),
    ],
)
def test_watch_bad_addresses_are_one_line(argv, words, tmp_path, capsys):
    if argv[0] == "--zenoh-config":
        bad = tmp_path / "bad.json5"
        bad.write_text("{ mode: 'peer', connect: { endpoints: ['tcp:127.0.0.1:1'] } }")
        argv = [argv[0], str(bad)]
    assert main(["watch", *argv, "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "cargo" not in err and "Json5Err" not in err
    assert err.count("cannot open a Zenoh session") <= 1, err  # the reason said once
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_train_quick_sets_the_budget_that_was_not_given_and_warns_on_a_short_one(tmp_path, capsys):
    from skyherd.scripts.train_irl import QUICK

    code = main(["train", "irl", "--quick", "--dqn-steps", "300", "--mu-episodes", "2",
                 "--eval-episodes", "1", "--demo-episodes", "1", "--runs-dir", str(tmp_path)])  # fmt: skip
    assert code == 0
    err = capsys.readouterr().err
    assert "warning: --dqn-steps 300 is not more than the DQN's learning_starts (1000)" in err
    (run,) = list(tmp_path.iterdir())
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["args"]["dqn_steps"] == 300 and cfg["args"]["seeds"] == QUICK["seeds"]
    assert cfg["args"]["irl_iters"] == QUICK["irl_iters"] and cfg["args"]["transfer_episodes"] == 0
    assert cfg["quick"] == ["--seeds 1", "--irl-iters 2", "--transfer-episodes 0"]
    assert cfg["command_line"].startswith("skyherd train irl --quick --dqn-steps 300")
    summary = (run / "summary.md").read_text()
    assert (
        "**Ended: completed**" in summary
        and "## Warnings" in summary
        and "learning_starts" in summary
    )
    assert QUICK["dqn_steps"] > 1000  # the quick budget itself learns something


def test_no_command_prints_help_and_is_bad_usage(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_every_command_has_examples_in_its_help_and_each_one_parses():
    """`skyherd CMD --help` ends with examples; each is a real command line its parser accepts
    (the part before `#` is the command)."""
    import shlex

    from skyherd.scripts.cli import COMMANDS, EXAMPLES
    from skyherd.scripts.train import EXAMPLES as TRAIN_EXAMPLES
    from skyherd.scripts.train import LEARNERS

    assert set(EXAMPLES) == set(COMMANDS) and set(TRAIN_EXAMPLES) == set(LEARNERS)
    helps = {n: p.format_help() for n, p in _walk(build_parser(None))}
    for name, lines in [*EXAMPLES.items(), *((f"train {k}", v) for k, v in TRAIN_EXAMPLES.items())]:
        text = helps[f"skyherd {name}"]
        assert "examples:\n" in text, name
        for line in lines:
            assert line in text, (name, line)
            argv = shlex.split(line.split("#", 1)[0])
            assert argv[0] == "skyherd"
            only = argv[1]
            args, extra = build_parser(only).parse_known_args(argv[1:])
            assert extra == [] and getattr(args, "_module", None) is not None, line


@pytest.mark.parametrize(
    "extra, speedup",
    [([], 0.0), (["--free-run"], 10.0), (["--connect", "udpin:127.0.0.1:14540"], 10.0),
     (["--speedup", "3"], 3.0)],
)  # fmt: skip
def test_fly_and_sim_share_one_speedup_default(extra, speedup):
    """--speedup: 0 in lockstep (the flight is the same at any speed-up: `skyherd fly` is
    `make run`'s flight), 10 when free-running (a pacer is needed); sim resolves it alike."""
    from skyherd.scripts import fly, sim

    args = build_parser("fly").parse_args(["fly", *extra])
    fly._check_own(args)
    assert args.speedup == speedup
    if "--connect" not in extra:
        s = build_parser("sim").parse_args(["sim", *extra])
        sim.check(s)
        assert s.speedup == speedup


def test_quick_has_one_meaning_in_every_command():
    """--quick: one help sentence everywhere (a smoke run, not results), and an option given
    on the command line wins over its budget (here `reproduce sql`'s)."""
    from skyherd.scripts import reproduce
    from skyherd.scripts.cli import QUICK_MEANING

    having = []
    for name, p in _walk(build_parser(None)):
        f = p._get_formatter()
        for a in p._actions:
            if "--quick" in a.option_strings:
                having.append(name)
                assert " ".join(f._expand_help(a).split()).startswith(QUICK_MEANING), name
    assert {"skyherd train sql", "skyherd train ab", "skyherd reproduce", "skyherd educate",
            "skyherd train abs-dl"} <= set(having)  # fmt: skip
    argv = ["reproduce", "sql", "--quick", "--episodes", "200"]
    args = build_parser("reproduce").parse_args(argv)
    args._argv = argv
    reproduce._check(args)
    assert (args.episodes, args.seeds, args.agents) == (200, 2, [9])
