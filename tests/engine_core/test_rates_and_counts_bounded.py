"""Rates and counts a run cannot honour are refused when the recipe is read, not met mid-run (a rate of
1e-300 Hz validated and then overflowed the source's sleep with a traceback; 10**30 frames validated)."""

from __future__ import annotations

import pytest

from engine.cli.main import main
from engine.exit_codes import ExitCode


@pytest.mark.parametrize(
    "override",
    [
        "source.rate_hz=1e-300",
        "source.rate_hz=0.0009",
        "source.rate_hz=1e9",
        "source.frames=1000000000000000000000000000000",
    ],
)
def test_an_unkeepable_rate_or_count_is_invalid(override: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate", "recipes/demo.yaml", "-p", override]) == ExitCode.INVALID
    said = capsys.readouterr()
    assert "<command line> -p" in said.out + said.err


@pytest.mark.parametrize(
    "override", ["source.rate_hz=0", "source.rate_hz=0.001", "source.rate_hz=30", "source.frames=0"]
)
def test_rates_and_counts_a_run_keeps_are_valid(override: str) -> None:
    assert main(["validate", "recipes/demo.yaml", "-p", override]) == ExitCode.OK
