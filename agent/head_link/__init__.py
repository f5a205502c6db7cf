"""The head's serial link: the wire protocol of ``docs/head-protocol.md`` (pure: bytes in,
frames and messages out; no port, no clock)."""
