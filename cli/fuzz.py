"""``sensor-agent fuzz [--messages N] [--seed S] [--json FILE]``: random and mutated messages
into every stage's inputs, as a process receives them (bytes, decoded and validated, then
the stage's ``handle``).

The stages are those of the closed loop (``launch/demo.toml``'s graph, built in code:
world, head, calibration, filtering, features, tracking, planner with the active policy,
vehicle), warmed up by 3 s of the demo world's run so that each holds real state. The seeds
of the mutations are the messages that run passed, by topic. Each of ``--messages`` per
stage input is one of:

* ``bytes``: its encoding with 1-8 random bytes overwritten, inserted or deleted;
* ``field``: one field set to a hostile value (NaN, ±inf, 1e300, −1, an empty or a
  mis-shaped array, a wrong type, a long string), re-encoded;
* ``values``: its values disturbed in type (arrays scaled, negated, zeroed, reversed or cut
  short; numbers scaled or replaced; flags flipped), many still valid: strange input that
  reaches ``handle``;
* ``random``: random bytes (0-400 of them).

Each goes in as a process takes it (:func:`feed`: the topic's size limit, decoded and
validated as the topic's type): it is refused (counted by ``MessageError`` kind: the
process's counters do the same) or reaches ``handle``, which must not raise: anything it
raises is a crash, counted and its first traceback kept. :func:`stage_inputs` and
:func:`feed` are shared with the property-based fuzzing (hypothesis) in
``tests/unit/test_fuzz_hypothesis.py``. Prints a table per stage and input; ``--json`` writes
``{"messages": .., "stages": {<stage>: {<topic>: {"sent", "rejected", "handled",
"crashes"}}}, "rejected_by_kind": {..}, "crashes": .., "first_crash": .., "stage_counters":
{<stage>: {..}}}`` (the last: what each stage itself dropped or refused of what it was
handed, as its heartbeat counts it). Exit status 1 on any crash.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
import traceback
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from agent.errors import MessageError
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner
from agent.runtime.messages import Message, decode, encode
from agent.runtime.stage import Stage
from agent.sim.world_file import load_world
from cli.closed_loop import closed_loop_nodes
from cli.output import write_json

ROOT = Path(__file__).resolve().parents[1]
WARM_UP_S = 3.0
HOSTILE: list[Any] = [
    math.nan, math.inf, -math.inf, 1e300, -1, 0, 2**63, "x" * 5000, [], {}, None, True,
    [[1.0, 2.0], [3.0]], b"\x00" * 17,
]  # fmt: skip


def _mutate_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 9))):
        how = int(rng.integers(0, 3))
        i = int(rng.integers(0, len(b) + 1))
        if how == 0 and i < len(b):
            b[i] = int(rng.integers(0, 256))
        elif how == 1:
            b.insert(i, int(rng.integers(0, 256)))
        elif b and i < len(b):
            del b[i]
    return bytes(b)


def _mutate_field(data: bytes, rng: np.random.Generator) -> bytes:
    """One field of the message's msgpack map set to a hostile value (the map kept)."""
    try:
        doc = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception:
        return _mutate_bytes(data, rng)
    if not isinstance(doc, dict) or not doc:
        return _mutate_bytes(data, rng)
    keys = list(doc)
    key = keys[int(rng.integers(0, len(keys)))]
    value = HOSTILE[int(rng.integers(0, len(HOSTILE)))]
    if isinstance(doc[key], dict) and doc[key] and rng.random() < 0.5:  # inside an array's map
        inner = list(doc[key])
        doc[key] = dict(doc[key])
        doc[key][inner[int(rng.integers(0, len(inner)))]] = value
    else:
        doc[key] = value
    packed: bytes = msgpack.packb(doc, use_bin_type=True)
    return packed


def _perturb(msg: Message, rng: np.random.Generator) -> bytes | None:
    """The message with its values (not its header) disturbed, in type: arrays scaled,
    negated, zeroed, reversed or cut short; numbers scaled or replaced; flags flipped. Many
    stay within the schema's ranges and reach ``handle`` as strange but valid input."""
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(msg):
        if f.name == "header" or rng.random() < 0.5:
            continue
        v = getattr(msg, f.name)
        if isinstance(v, np.ndarray) and v.size:
            how = int(rng.integers(0, 5))
            if how == 0 and v.dtype.kind == "f":
                v = v * rng.uniform(-3.0, 3.0)
            elif how == 1:
                v = np.zeros_like(v)
            elif how == 2:
                v = v[::-1].copy()
            elif how == 3:
                v = v[: int(rng.integers(0, v.shape[0] + 1))].copy()
            elif v.dtype.kind in "iu":
                v = (v + rng.integers(-3, 4, v.shape)).astype(v.dtype)
            changes[f.name] = v
        elif isinstance(v, bool):
            changes[f.name] = not v
        elif isinstance(v, float):
            changes[f.name] = float(v * rng.uniform(-3.0, 3.0) if rng.random() < 0.5
                                    else rng.uniform(-10.0, 10.0))  # fmt: skip
        elif isinstance(v, int):
            changes[f.name] = int(v + rng.integers(-5, 6))
    try:
        return encode(dataclasses.replace(msg, **changes))  # type: ignore[type-var]
    except Exception:
        return None


@dataclass(frozen=True)
class StageInput:
    """One input of one of the closed loop's stages, warmed up: the stage's name, the stage
    (shared by its inputs), the topic, and the messages the warm-up passed on it."""

    stage_name: str
    stage: Stage
    topic: str
    seeds: list[Message]


def stage_inputs() -> list[StageInput]:
    """Every input of the closed loop's stages after :data:`WARM_UP_S` s of the demo world's
    run, in the graph's order."""
    world = load_world(ROOT / "worlds" / "demo.toml")
    assert world.task is not None
    nodes, _, _ = closed_loop_nodes(world, world.task, "active", "default", 0)
    runner = LockstepRunner(nodes)
    by_topic: dict[str, list[Message]] = defaultdict(list)

    def seen(t: float, topic: str, msg: Message) -> None:
        if len(by_topic[topic]) < 50:
            by_topic[topic].append(msg)

    runner.observe(seen)
    runner.run_until(WARM_UP_S)
    return [
        StageInput(node.name, node.stage, topic, list(by_topic.get(topic, [])))
        for node in nodes
        for topic in node.inputs
    ]


def feed(stage: Stage, topic: str, payload: bytes, now_s: float) -> str | None:
    """One message into ``stage`` as a process takes it (``processes.runtime``): a payload
    over the topic's size limit, or one that does not decode and validate as the topic's
    type, is refused, and the ``MessageError`` kind returned; anything else the stage
    handles, and ``None`` is returned. What the stage raises is not caught."""
    if len(payload) > topics.MAX_BYTES[topic]:
        return "oversized"
    try:
        msg = decode(payload, expect=topics.message_type(topic))
    except MessageError as exc:
        return exc.kind
    stage.handle(topic, msg, now_s)
    return None


def run(messages: int, seed: int) -> dict[str, Any]:
    """Every stage input's fuzzing (module docstring)."""
    rng = np.random.default_rng(seed)
    inputs = stage_inputs()
    stages: dict[str, dict[str, dict[str, int]]] = defaultdict(dict)
    rejected: Counter[str] = Counter()
    crashes = 0
    first_crash = ""
    now = WARM_UP_S
    for one in inputs:
        originals = one.seeds
        base = [encode(m) for m in originals]
        tally = {"sent": 0, "rejected": 0, "handled": 0, "crashes": 0}
        for _ in range(messages):
            pick = rng.random()
            if not base or pick < 0.1:
                data = rng.integers(0, 256, int(rng.integers(0, 401)), dtype=np.uint8)
                payload = data.tobytes()
            elif pick < 0.4:
                payload = _mutate_bytes(base[int(rng.integers(0, len(base)))], rng)
            elif pick < 0.6:
                payload = _mutate_field(base[int(rng.integers(0, len(base)))], rng)
            else:
                k = int(rng.integers(0, len(base)))
                perturbed = _perturb(originals[k], rng)
                payload = perturbed if perturbed is not None else base[k]
            tally["sent"] += 1
            now += 0.001
            try:
                kind = feed(one.stage, one.topic, payload, now)
            except Exception:
                tally["crashes"] += 1
                crashes += 1
                if not first_crash:
                    first_crash = f"{one.stage_name} <- {one.topic}:\n{traceback.format_exc()}"
                continue
            if kind is None:
                tally["handled"] += 1
            else:
                tally["rejected"] += 1
                rejected[kind] += 1
        stages[one.stage_name][one.topic] = tally
    return {
        "messages": messages, "seed": seed, "stages": dict(stages),
        "rejected_by_kind": dict(rejected), "crashes": crashes, "first_crash": first_crash,
        # What each stage itself dropped or refused of what it was handed (its heartbeat's).
        "stage_counters": {one.stage_name: one.stage.counters() for one in inputs},
    }  # fmt: skip


def fuzz_command(args: argparse.Namespace) -> int:
    """``sensor-agent fuzz``: the table, and ``--json``."""
    started = time.perf_counter()
    doc = run(args.messages, args.seed)
    print(f"stage inputs fuzzed: {args.messages} messages each (seed {args.seed})")
    print(f"  {'stage':12s} {'input':16s} {'sent':>8s} {'rejected':>9s} {'handled':>8s} "
          f"{'crashes':>8s}")  # fmt: skip
    for stage, inputs in doc["stages"].items():
        for topic, t in inputs.items():
            print(f"  {stage:12s} {topic:16s} {t['sent']:8d} {t['rejected']:9d} "
                  f"{t['handled']:8d} {t['crashes']:8d}")  # fmt: skip
    kinds = ", ".join(f"{k} {v}" for k, v in sorted(doc["rejected_by_kind"].items()))
    print(f"  rejected at decoding, by kind: {kinds}")
    print(f"  crashes: {doc['crashes']}  ({time.perf_counter() - started:.0f} s)")
    if doc["first_crash"]:
        print(doc["first_crash"])
    if args.json:
        write_json(Path(args.json), doc)
    return 1 if doc["crashes"] else 0
