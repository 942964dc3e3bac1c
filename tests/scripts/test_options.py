"""Options generated from a frozen dataclass (scripts/options.py): one field, one option, with
its default, its type and its help."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import pytest

from skyherd.scripts.cli import Parser
from skyherd.scripts.options import add_options, field_docs, opt, values


@dataclass(frozen=True)
class _Demo:
    """Options of a made-up command."""

    steps: int = 100  # env steps
    rate_hz: float = 2.5
    """decisions per second, said on
    two lines"""
    seeds: tuple[int, ...] = (0, 1)  # learner seeds
    out: Path | None = opt(None, aliases=("--output",))  # where it goes
    mode: str = opt("a", choices=("a", "b"))  # which mode
    dry: bool = False  # write nothing
    shield: bool = True  # the safety net on


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="demo")
    add_options(p, _Demo)
    return p


def test_help_comes_from_the_comment_or_the_docstring_under_the_field():
    docs = field_docs(_Demo)
    assert docs["steps"] == "env steps"
    assert docs["rate_hz"] == "decisions per second, said on two lines"
    assert docs["shield"] == "the safety net on"


def test_defaults_types_and_flags_follow_the_fields():
    a = _parser().parse_args([])
    assert (a.steps, a.rate_hz, a.seeds, a.out, a.mode, a.dry, a.shield) == (
        100, 2.5, [0, 1], None, "a", False, True
    )  # fmt: skip
    a = _parser().parse_args(["--steps", "7", "--rate-hz", "1", "--seeds", "3", "4", "5",
                              "--output", "x", "--mode", "b", "--dry", "--no-shield"])  # fmt: skip
    assert (a.steps, a.rate_hz, a.seeds, a.out, a.mode, a.dry, a.shield) == (
        7, 1.0, [3, 4, 5], Path("x"), "b", True, False
    )  # fmt: skip
    with pytest.raises(SystemExit):
        _parser().parse_args(["--mode", "c"])


def test_every_option_shows_its_help_and_default():
    text = " ".join(_parser().format_help().split())
    for words in ("env steps (default: 100)", "learner seeds (default: 0 1)",
                  "decisions per second, said on two lines (default: 2.5)",
                  "the safety net on (default: on)", "--out OUT, --output OUT"):  # fmt: skip
        assert words in text


@dataclass(frozen=True)
class _Lower:
    """A lower layer's parameters: no argparse in them."""

    rate_hz: float = 2.0  # decisions per second
    timeout_s: float = 10.0  # give up after this long [s]
    show: bool = True  # a window


def test_a_lower_layers_fields_shown_as_the_command_says_in_its_order():
    """Several classes (a name two have is the first's), `only`'s order, a flag and dest given."""
    p = Parser(prog="demo")
    order = ("timeout_s", "steps", "rate_hz")
    timeout = dict(flag="--timeout", dest="timeout")
    add_options(p, (_Lower, _Demo), only=order, rate_hz=dict(flag="--rate"), timeout_s=timeout)
    text = " ".join(p.format_help().split())
    assert "[--timeout TIMEOUT] [--steps STEPS] [--rate RATE]" in text
    assert "decisions per second (default: 2.0)" in text and "--show" not in text
    a = p.parse_args(["--rate", "5", "--timeout", "3"])
    assert (a.rate_hz, a.timeout, a.steps) == (5.0, 3.0, 100)
    assert values(_Lower, a, timeout_s=a.timeout, show=False) == _Lower(5.0, 3.0, False)
