"""The one command-line pattern shared by every module.

Each command module (``capture.run``, ``capture.replay``, ``capture.review``, ``capture.ingest``,
``capture.raw``, ``capture.evk``, ``capture.gopro``, ``sim.dataset``) has

- ``build_parser() -> argparse.ArgumentParser`` whose ``prog`` is ``python -m <module>``, using
  the ``type=`` helpers below, so that an option is spelled and parsed the same everywhere
  (``--roi X,Y,WIDTH,HEIGHT``, ``--bias NAME=VALUE``, ``--quiet``);
- ``main(argv=None) -> int`` that parses, then runs its body through :func:`run_command`:
  an error is printed as one line ``<module>: error: <reason>`` (e.g. ``capture.replay: error: ...``)
  and gives exit code 1 (a usage error is argparse's, exit code 2), Ctrl-C gives 130, never a
  traceback.

The ``courtside`` console script (:mod:`capture.cli`) dispatches its subcommands to these ``main``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable

from capture.events import BALL_DIAMETER_M

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


def box(text: str) -> tuple[int, int, int, int]:
    """argparse type: four comma-separated integers, e.g. ``--roi X,Y,WIDTH,HEIGHT`` (px)."""
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f"expected four comma-separated integers, got {text!r}")
    return values


def name_int(text: str) -> tuple[str, int]:
    """argparse type: ``NAME=VALUE`` with an integer value (``--bias bias_fo=10``); use with
    ``action="append"`` and turn the pairs into a dict."""
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name, int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: {value!r} is not an integer") from None


FLICKER_BANDS_HZ = {"50Hz": (90, 110), "60Hz": (110, 130)}
"""Anti-flicker bands for the mains frequency: lights flicker at twice it."""


def flicker_band(text: str) -> tuple[int, int]:
    """argparse type: the event camera's anti-flicker band, ``50Hz`` / ``60Hz`` (the mains
    frequency: 90-110 / 110-130 Hz) or ``LOW,HIGH`` in Hz."""
    if text in FLICKER_BANDS_HZ:
        return FLICKER_BANDS_HZ[text]
    try:
        low, high = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 50Hz, 60Hz or LOW,HIGH in Hz, got {text!r}") from None
    return low, high


def trail_filter(text: str) -> tuple[str, int]:
    """argparse type: the event camera's trail filter, ``KIND`` or ``KIND:MS`` with KIND one of
    ``trail``, ``stc-cut``, ``stc-keep`` and MS the longest gap within a burst (1-100 ms,
    default 10); returns ``(kind, threshold_us)`` as ``capture.evk.Camera.set_trail_filter``
    takes them."""
    kind, colon, ms = text.partition(":")
    if kind not in ("trail", "stc-cut", "stc-keep"):
        raise argparse.ArgumentTypeError(f"expected trail, stc-cut or stc-keep[:MS], got {text!r}")
    try:
        threshold_ms = int(ms) if colon else 10
    except ValueError:
        raise argparse.ArgumentTypeError(f"{kind}: {ms!r} is not a whole number of ms") from None
    if not 1 <= threshold_ms <= 100:
        raise argparse.ArgumentTypeError(f"{kind}: {threshold_ms} ms is outside 1-100 ms")
    return kind.replace("-", "_"), threshold_ms * 1000


def add_sensor_mode_args(ap: argparse.ArgumentParser) -> None:
    """The event camera's ``--trail-filter``, ``--sync`` and ``--event-format`` options (IMX636),
    and ``--usb-transfers``."""
    ap.add_argument("--trail-filter", type=trail_filter, metavar="trail|stc-cut|stc-keep[:MS]",
                    help="event camera: filter event bursts in the sensor (trail: first event of each "
                         "burst; stc-cut: one event per edge, lone noise events dropped; stc-keep: the "
                         "burst less its first event, noise dropped; MS: burst gap, default 10)")
    ap.add_argument("--sync", choices=["standalone", "master", "slave"],
                    help="event camera: time base shared over the SYNC cable (start the slave first)")
    ap.add_argument("--event-format", choices=["EVT3", "EVT21"],
                    help="event camera: output format (default EVT3; EVT21 takes about 4x the bandwidth)")
    ap.add_argument("--usb-transfers", type=positive_int, metavar="N",
                    help="event camera: USB requests kept in flight (default 64; 1 reads one at a time)")


def frequency_hz(text: str) -> float:
    """argparse type: a frequency in Hz, finite and > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frequency in Hz, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of Hz, got {text}")
    return value


def flicker_hz(text: str) -> float | str:
    """argparse type: a light's flicker frequency in Hz (finite and > 0), or ``auto`` (found in the
    events: ``detect.BallTracker``'s ``flicker_hz="auto"``)."""
    return "auto" if text.strip().lower() == "auto" else frequency_hz(text)


def positive_int(text: str) -> int:
    """argparse type: an integer > 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {value}")
    return value


def add_ball_args(ap: argparse.ArgumentParser) -> None:
    """``--ball`` (a preset) or ``--ball-diameter`` (metres); :func:`ball_diameter_m` reads them back."""
    ball = ap.add_mutually_exclusive_group()
    ball.add_argument("--ball", choices=sorted(BALL_DIAMETER_M), help="the ball, for distances and speeds")
    ball.add_argument("--ball-diameter", type=float, metavar="M", help="the ball's diameter in metres")


def ball_attr(args) -> dict | None:
    """The session attribute ``ball`` (``{"type": preset or None, "diameter_m": m}``) from the
    arguments of :func:`add_ball_args`, or None when neither is given."""
    diameter = ball_diameter_m(args)
    return None if diameter is None else {"type": args.ball, "diameter_m": diameter}


def ball_diameter_m(args) -> float | None:
    """The ball's diameter (m) from the arguments of :func:`add_ball_args`, or None when neither is given.

    Raises
    ------
    ValueError
        ``--ball-diameter`` is not positive.
    """
    if args.ball_diameter is not None and not args.ball_diameter > 0:
        raise ValueError(f"--ball-diameter must be positive, got {args.ball_diameter}")
    return args.ball_diameter or (BALL_DIAMETER_M[args.ball] if args.ball else None)


def print_fields(d: dict) -> None:
    """Print ``key: value`` lines (nested dicts indented; floats rounded; None left out)."""
    for key, value in d.items():
        if isinstance(value, dict):
            print(f"{key}:")
            for k, v in value.items():
                print(f"  {k}: {v}")
        elif value is not None:
            print(f"{key}: {round(value) if isinstance(value, float) else value}")


def run_command(prog: str, body: Callable[[], int | None]) -> int:
    """Run a command's body; return its exit code (None: 0).

    Any exception becomes one line on stderr, ``<module>: error: <message>`` (``prog`` without a
    leading ``python -m``; the exception's type is named when it is not one of ours or an OS /
    value error), and exit code 1; Ctrl-C gives 130.
    """
    prog = prog.removeprefix("python -m ")
    try:
        code = body()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # the command line's promise: one line, never a traceback
        print(f"{prog}: error: {describe(exc)}", file=sys.stderr)
        return EXIT_ERROR
    return 0 if code is None else int(code)


def describe(exc: BaseException) -> str:
    """One line for an exception: its message, prefixed with its type unless that is one of this
    project's errors (their messages are written for the user) or an OS / value error."""
    message = " ".join(str(exc).split()) or type(exc).__name__
    ours = type(exc).__module__.split(".")[0] in {"capture", "detect", "spin", "calib", "sim"}
    if ours or isinstance(exc, (OSError, ValueError)):
        return message
    return f"{type(exc).__name__}: {message}"
