"""viz: the only package that imports rerun (lazily, inside :mod:`viz.rerun_sink`)."""
from viz.sink import NullSink, Sink, make_sink

__all__ = ["Sink", "NullSink", "make_sink"]
