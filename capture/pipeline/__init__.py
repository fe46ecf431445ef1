"""The pipeline layer: the only part of the project that joins devices, detection and spin.

- :mod:`capture.pipeline.record`: record one session from the event camera (real or fake)
  and optionally a GoPro, with live analysis beside it.
- :mod:`capture.pipeline.live`: ball tracking and spin on the incoming stream, never
  slowing the recording.
- :mod:`capture.pipeline.replay`: detection and spin over a stored session, in independent
  units of work (one tracking unit per session, spin parts per flight).
- :mod:`capture.pipeline.workers`: the units shared between worker processes and the caller.
- :mod:`capture.pipeline.demo`: the built-in demo's inputs (a simulated rally on the fake devices).

Everything below it (``capture.events``, ``capture.session``, ``capture.raw``, ``capture.evk``,
``capture.gopro``, ``capture.ingest``, ``capture.review``, ``detect``, ``spin``, ``calib``,
``sim``) never imports it; the command lines (``capture.run``, ``capture.replay``,
``capture.cli``) sit above it.
"""
