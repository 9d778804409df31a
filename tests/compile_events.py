"""Counting JAX's own compile events by function name, for tests that a call is not traced or compiled again."""

import jax

BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
TRACE = "/jax/core/compile/jaxpr_trace_duration"  # a retrace shows here even where the session's disk cache spares the compile


class EventCounter:
    """Events of one kind per function name while active (registered once: JAX cannot unregister)."""

    def __init__(self, event: str):
        self.event, self.counts, self.active = event, {}, False
        jax.monitoring.register_event_duration_secs_listener(self.listen)

    def listen(self, event, duration, **kwargs):
        if self.active and event == self.event:
            name = kwargs.get("fun_name", "?")
            self.counts[name] = self.counts.get(name, 0) + 1
