"""The agent's stages: pure logic mapping input messages (and a time) to output messages.

The same stage objects run inside a process shell (``processes/``) on the wall clock, and in
the lock-step runner (:mod:`agent.runtime.lockstep`) on a simulated clock.
"""
