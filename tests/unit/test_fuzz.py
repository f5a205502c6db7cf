"""sensor-agent fuzz, a short run: random and mutated messages into every stage's inputs,
decoded and validated as a process does, never crash a stage (the command's full run sends
10⁵ per input)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cli.fuzz import fuzz_command


def test_no_stage_crashes_on_random_or_mutated_input(tmp_path: Path) -> None:
    out = tmp_path / "fuzz.json"
    assert fuzz_command(argparse.Namespace(messages=150, seed=3, json=str(out))) == 0
    doc = json.loads(out.read_text())
    assert doc["crashes"] == 0 and doc["first_crash"] == ""
    inputs = [(s, t, c) for s, ins in doc["stages"].items() for t, c in ins.items()]
    assert len(inputs) == 16  # every input of the closed loop's eight stages
    for stage, topic, c in inputs:
        assert c["sent"] == 150 and c["rejected"] + c["handled"] == 150, (stage, topic)
        # Both paths are exercised: refused at decoding (counted by kind) and handled.
        assert c["rejected"] > 0 and c["handled"] > 0, (stage, topic)
    assert sum(doc["rejected_by_kind"].values()) == sum(c["rejected"] for *_, c in inputs)
