"""Sinks: estimates -> Zenoh, Rerun, files. Each sink implements :class:`Sink`."""

from glmav_observer.publish.sink import Sink

__all__ = ["Sink"]
