"""What a review looks like: recording ids, timeline, entity paths, colours and the blueprint.

One Rerun recording per session (application id :data:`APPLICATION_ID`), on the
timeline :data:`TIMELINE` (``sensor_time``): µs on the event clock, stored as a
Rerun *duration* so that the viewer shows seconds since the sensor's time zero.

Entity layout (shared by :func:`capture.review.write_rrd` and :class:`capture.review.LiveReview`)::

    events/on, events/off        Points2D: events of one time slice (ON sky blue, OFF orange, on black);
                                 offline, a full slice is thinned outside the ball first
    events/sensor                Boxes2D (static): the sensor outline
    events/ball                  Ellipses2D: ball circle from the track, labelled with its flight
    events/spin_axis             Arrows2D: spin axis projected on the image, at the ball centre
    events/spin_pole             Points2D: the pole of the spin axis on the camera's side of the ball
                                 (seen even when the axis points at the camera), labelled with the rpm
    ball/image                   Image: the ball's events of a spin window, ball-centred: as recorded
                                 (left) and turned back by the estimated spin (right, sharp if it fits)
    ball/rim, ball/axis          Ellipses2D, Arrows2D: the ball's rim and spin axis on that image
    frames/image                 EncodedImage (JPEG) or VideoFrameReference into video/asset
    frames/ball                  Ellipses2D: ball circle mapped into the frame (needs calibration)
    frames/note                  Points2D (static): why the frames show no ball circle
    video/asset                  AssetVideo (static): the session's MP4, when it has one
    ball3d/sphere, ball3d/axis   Ellipsoids3D (static) and Arrows3D: unit ball and spin axis
                                 (grey when not trusted)
    plots/rps                    Scalars: spin rate, rev/s
    plots/rpm/trusted            Scalars: spin rate of the trusted windows (confidence >= 0.5), rpm
    plots/rpm/not_trusted        Scalars: spin rate of the other windows, rpm (drawn grey)
    plots/rpm/flight             Scalars: each flight's rate (median of its trusted windows) over the flight
    plots/rpm/truth              Scalars: the simulated truth (demo sessions), rpm
    plots/spin/<part>_rpm        Scalars: topspin, sidespin, gyro in the flight's frame, rpm
                                 (:mod:`capture.results`; they do not wrap as angles do)
    plots/spin/truth_<part>_rpm  Scalars: the same of the simulated truth (demo sessions)
    plots/speed/image_px_s       Scalars: the ball's image speed from the track, px/s
    plots/speed/flight_m_s       Scalars: each flight's 3D speed over the flight (ball size and calibration known)
    plots/axis/azimuth_deg       Scalars: axis azimuth, see :func:`axis_angles_deg`
    plots/axis/elevation_deg     Scalars: axis elevation
    plots/confidence             Scalars: spin confidence 0..1
    plots/confidence/trust       Scalars: the trust threshold (:data:`capture.results.TRUST`)
    plots/uncertainty/rps_pct    Scalars: spin-rate uncertainty (1 sigma), %
    plots/uncertainty/axis_deg   Scalars: spin-axis uncertainty (1 sigma), deg
    plots/uncertainty/ball_px    Scalars: the track's circle uncertainty (1 sigma), px
    plots/event_rate/events_ev_s Scalars: event rate per slice (before decimation), ev/s
    plots/status/<name>          Scalars: live status numbers (drops, ...)
    log                          TextLog: notes (decimation, skipped batches, flight starts and ends, ...)
    results/flights              TextDocument (static): the per-flight table (:mod:`capture.results`)

2D entities use Rerun's image coordinates, where pixel ``(0, 0)`` covers
``[0, 1) x [0, 1)``: a pixel coordinate ``u`` (pixel centre at integer values,
see conventions) is logged as ``u + PIXEL_OFFSET``.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

if TYPE_CHECKING:
    from capture.session import Session

APPLICATION_ID = "courtside-spin"
TIMELINE = "sensor_time"
PIXEL_OFFSET = 0.5
"""Added to pixel coordinates when logging 2D entities (Rerun puts pixel centres at +0.5)."""

EVENTS_ON = "events/on"
EVENTS_OFF = "events/off"
EVENTS_SENSOR = "events/sensor"
EVENTS_BALL = "events/ball"
EVENTS_SPIN_AXIS = "events/spin_axis"
EVENTS_SPIN_POLE = "events/spin_pole"
BALL_IMAGE = "ball/image"
BALL_RIM = "ball/rim"
BALL_AXIS = "ball/axis"
FRAMES_IMAGE = "frames/image"
FRAMES_BALL = "frames/ball"
FRAMES_NOTE = "frames/note"
VIDEO_ASSET = "video/asset"
BALL3D = "ball3d"
BALL3D_SPHERE = "ball3d/sphere"
BALL3D_AXIS = "ball3d/axis"
PLOT_RPS = "plots/rps"
PLOT_RPM_TRUSTED = "plots/rpm/trusted"
PLOT_RPM_UNTRUSTED = "plots/rpm/not_trusted"
PLOT_RPM_FLIGHT = "plots/rpm/flight"
PLOT_RPM_TRUTH = "plots/rpm/truth"
PLOT_SPIN_PARTS = "plots/spin"
PLOT_SPEED_IMAGE = "plots/speed/image_px_s"
PLOT_SPEED_FLIGHT = "plots/speed/flight_m_s"
PLOT_AZIMUTH = "plots/axis/azimuth_deg"
PLOT_ELEVATION = "plots/axis/elevation_deg"
PLOT_CONFIDENCE = "plots/confidence"
PLOT_TRUST = "plots/confidence/trust"
PLOT_RPS_SIGMA = "plots/uncertainty/rps_pct"
PLOT_AXIS_SIGMA = "plots/uncertainty/axis_deg"
PLOT_BALL_SIGMA = "plots/uncertainty/ball_px"
PLOT_EVENT_RATE = "plots/event_rate/events_ev_s"
PLOT_STATUS = "plots/status"
TEXT_LOG = "log"
RESULTS_FLIGHTS = "results/flights"

# colours, RGB 0..255
ON_COLOR = (86, 180, 233)
OFF_COLOR = (230, 159, 0)
"""Polarity colours: Okabe-Ito sky blue and orange, told apart with any colour vision, on black."""
BALL_COLOR = (255, 210, 0)
AXIS_COLOR = (80, 160, 255)
UNTRUSTED_COLOR = (150, 150, 150)
TRUTH_COLOR = (0, 158, 115)
"""Okabe-Ito bluish green: reference lines of the simulated truth."""

DEFAULT_SLICE_US = 2000
"""Event slice length, µs."""
DEFAULT_MAX_EVENTS_PER_SLICE = 2000
"""Events logged per slice away from the ball at most; a fuller slice is decimated by a stride."""
DEFAULT_MAX_BALL_EVENTS_PER_SLICE = 12000
"""Events logged per slice on the ball (within 1.25 radii of the track's circle) at most."""


def time_column(t_us) -> rr.TimeColumn:
    """Times ``t_us`` (µs, shape (N,)) as a column of :data:`TIMELINE` (a Rerun duration)."""
    return rr.TimeColumn(TIMELINE, duration=np.asarray(t_us, dtype=np.int64).astype("timedelta64[us]"))


def axis_angles_deg(axis) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (degrees) of unit spin axes in the camera frame (X right, Y down, Z forward).

    ``azimuth = atan2(x, z)``: 0 along +Z (away from the camera), +90 along +X (right).
    ``elevation = asin(-y)``: +90 pointing up (-Y), -90 pointing down.

    Parameters
    ----------
    axis : array_like, shape (N, 3)

    Returns
    -------
    azimuth_deg, elevation_deg : ndarray of float64, shape (N,)
    """
    a = np.asarray(axis, dtype=np.float64).reshape(-1, 3)
    norm = np.linalg.norm(a, axis=1)
    a = a / np.where(norm > 0, norm, 1.0)[:, None]
    return np.degrees(np.arctan2(a[:, 0], a[:, 2])), np.degrees(np.arcsin(np.clip(-a[:, 1], -1.0, 1.0)))


def circle_mapping(attrs: Mapping) -> Callable[[np.ndarray], np.ndarray] | None:
    """Event-sensor circles -> frame circles, ``(N, 3) -> (N, 3)`` px, from the session's calibration.

    Uses ``attrs["calibration"]`` (a :class:`calib.stereo.CameraPair` dict: stereo model
    or homography). Returns None when the session has no calibration.
    """
    from calib.stereo import CameraPair  # imports OpenCV: only when a session is reviewed

    calib = attrs.get("calibration")
    if not isinstance(calib, Mapping):
        return None
    pair = CameraPair.from_dict(calib)
    if pair.homography is None and pair.extrinsics is None:
        return None
    return pair.event_to_frame


def session_recording_id(session: Session) -> str:
    """Stable Rerun recording id of a session (from its resolved path and creation time)."""
    key = f"{session.path.resolve()}|{session.attrs.get('created_utc', '')}"
    return str(uuid.uuid5(uuid.NAMESPACE_URL, key))


def blueprint(*, frames: bool = True, width: int | None = None, height: int | None = None,
              status: bool = False, follow: bool = True, first_flight_us: tuple[int, int] | None = None,
              ball_view: bool = False) -> rrb.Blueprint:
    """The review layout, made to fit a 1366x768 screen: the events, the ball close-up, the GoPro
    frames and the 3D spin axis on top; spin rate, spin in the flight's frame, speed and (in tabs)
    confidence, uncertainty and event rate below; the flight table and the log at the bottom. The
    blueprint and selection panels start collapsed.

    Parameters
    ----------
    frames : bool
        Include the GoPro frames view.
    width, height : int, optional
        Sensor size in pixels, to frame the events view.
    status : bool
        Include live status numbers (drops, ...) with the event rate.
    follow : bool
        The viewer follows the newest data (live); else it opens paused.
    first_flight_us : (int, int), optional
        The first flight's start and end, µs: selected on the timeline, and played in a loop at
        a tenth of real speed (offline), so that the viewer opens on the ball in flight.
    ball_view : bool
        Include the ball close-up (:data:`BALL_IMAGE`, offline).
    """
    bounds = (rrb.VisualBounds2D(x_range=[0, width], y_range=[0, height])
              if width and height else None)
    top = [rrb.Spatial2DView(origin="events", name="Events", visual_bounds=bounds, background=[0, 0, 0])]
    if ball_view:
        top.append(rrb.Spatial2DView(origin="ball", name="Ball: recorded | spin removed", background=[0, 0, 0]))
    if frames:
        top.append(rrb.Spatial2DView(origin="frames", name="GoPro"))
    top.append(rrb.Spatial3DView(origin=BALL3D, name="Spin axis"))
    rate_contents = ["+ /plots/event_rate/**"] + (["+ /plots/status/**"] if status else [])
    bottom = [
        rrb.TimeSeriesView(origin="plots/rpm", name="Spin (rpm)"),
        rrb.TimeSeriesView(origin=PLOT_SPIN_PARTS, name="Top/side/gyro (rpm)"),
        rrb.TimeSeriesView(origin="plots/speed", name="Speed"),
        rrb.Tabs(rrb.TimeSeriesView(origin=PLOT_CONFIDENCE, name="Confidence"),
                 rrb.TimeSeriesView(origin="plots/uncertainty", name="1 sigma (%, deg, px)"),
                 rrb.TimeSeriesView(origin="plots", contents=rate_contents,
                                    name="Events/s" + (" + status" if status else ""))),
    ]
    texts = [rrb.TextDocumentView(origin=RESULTS_FLIGHTS, name="Flights"), rrb.TextLogView(origin=TEXT_LOG, name="Log")]
    time_panel = {"timeline": TIMELINE, "state": "collapsed"}
    if follow:
        time_panel["play_state"] = "following"
    elif first_flight_us is not None:
        t0, t1 = (rr.encodings.TimeInt(nanos=int(t) * 1000) for t in first_flight_us)  # a duration timeline: ns
        time_panel.update(play_state="playing", loop_mode="selection", playback_speed=0.1,
                          time_selection=rrb.components.AbsoluteTimeRange(t0, t1))
    else:
        time_panel["play_state"] = "paused"
    return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*top), rrb.Horizontal(*bottom),
                                      rrb.Horizontal(*texts, column_shares=[3, 1]), row_shares=[6, 4, 2]),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(**time_panel))
