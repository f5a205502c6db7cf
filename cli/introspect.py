"""Introspection and replay commands: topics, echo, hz, replay."""

from __future__ import annotations

import argparse
from typing import Any


def add_commands(sub: Any) -> None:
    """Register the subcommands on the main parser's subparsers object."""
    del sub


def _unused(args: argparse.Namespace) -> int:
    return 0
