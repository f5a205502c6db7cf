"""The bench's realistic messages and its codec figures, on tiny counts (no sockets)."""

from __future__ import annotations

import json
import math

import pytest

from agent.runtime import topics
from agent.runtime.messages import decode
from cli.bench_codec import codec_figures, message_bytes
from cli.bench_messages import graph_messages, raw_scans
from cli.output import jsonable

GRAPH_TYPES = {
    "raw_scan", "calibrated_scan", "filtered_scan", "features",
    "vehicle_state", "head_command", "head_state", "heartbeat", "world_truth",
}  # fmt: skip


@pytest.fixture(scope="module")
def samples() -> dict[str, list]:
    return graph_messages(raw_scans(3))


def test_realistic_messages_cover_the_graph_and_survive_their_own_decoding(samples) -> None:
    assert set(samples) >= GRAPH_TYPES
    for topic in ("raw_scan", "calibrated_scan", "filtered_scan", "features"):
        assert [m.sweep_index for m in samples[topic]] == [0, 1, 2]
    for topic, msgs in samples.items():
        cls = topics.message_type(topic)
        for msg in msgs:
            assert isinstance(decode(msg.to_wire(), expect=cls), cls)
    # Real scans: a filtered scan of 256 samples dwarfs the small messages.
    sizes = message_bytes(samples)
    assert sizes["filtered_scan"] > 10_000 > 1_000 > sizes["head_command"]


def test_codec_figures_are_positive_finite_per_type(samples) -> None:
    figures = codec_figures(samples, calls=5)
    assert set(figures) == set(samples)
    for topic, us in figures.items():
        assert set(us) == {"encode", "decode"}, topic
        assert all(math.isfinite(v) and v > 0 for v in us.values()), (topic, us)
    json.dumps(jsonable(figures), allow_nan=False)


def test_codec_figures_refuse_no_calls(samples) -> None:
    with pytest.raises(ValueError, match="calls"):
        codec_figures(samples, calls=0)


@pytest.mark.parametrize(
    ("flag", "value"), [("--hop-round-trips", "0"), ("--codec-calls", "0"), ("--hop-warm-up", "-1")]
)
def test_bench_refuses_counts_it_cannot_measure_with(flag: str, value: str, capsys) -> None:
    from cli.main import main

    assert main(["bench", flag, value]) == 2
    assert flag in capsys.readouterr().err
