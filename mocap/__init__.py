"""mocap: marker recordings in, link angles out.

Readers convert to time-first arrays in metres once, at the file boundary.
"""
from mocap.io.errors import InputError
from mocap.io.recording import MarkerRecording

__all__ = ["InputError", "MarkerRecording"]
