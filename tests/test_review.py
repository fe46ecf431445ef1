"""Rerun review: write a small session's .rrd, read it back with rerun's own reader, check values."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from capture import review
from capture.events import Track, make_events, make_triggers
from capture.review.cli import main
from capture.session import SessionError, create_session, open_session

SLICE_US = 1000
CAP = 500
H_FRAME_FROM_EVENT = [[0.5, 0.0, 3.0], [0.0, 0.5, 4.0], [0.0, 0.0, 1.0]]
SLICES = {10_000: 300, 11_000: 1200, 15_000: 700}
"""Slice start (µs) -> number of events; 12-15 ms is empty; 1200 and 700 exceed CAP."""


@pytest.fixture(autouse=True, scope="module")
def _rerun_strict():
    """Make Rerun raise on bad data instead of logging a warning."""
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def _events(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.concatenate([np.sort(rng.integers(t0, t0 + SLICE_US, n)) for t0, n in SLICES.items()])
    n = len(t)
    return make_events(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.integers(0, 2, n))


def _track() -> Track:
    t = np.r_[np.arange(10_000, 13_001, 500), np.arange(15_000, 16_001, 500)]
    flight = np.r_[np.zeros(7, int), np.ones(3, int)]
    return Track(t_us=t, cx=10.0 + 0.004 * (t - 10_000), cy=20.0 + flight * 5, r=np.where(flight, 6.0, 8.0),
                 vx=np.full(len(t), 4000.0), vy=np.zeros(len(t)), score=np.ones(len(t)), flight=flight,
                 sigma_px=np.r_[np.nan, np.nan, np.linspace(0.2, 1.6, 8)])  # the first two not measured


SPIN = {"t_start_us": np.array([10_000, 11_000, 15_000]), "t_end_us": np.array([11_000, 12_000, 16_000]),
        "axis": np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0.6, 0.8]]),
        "omega_rad_s": 2 * np.pi * np.array([10.0, 20.0, 30.5]), "rps": np.array([10.0, 20.0, 30.5]),
        "velocity_px_s": np.zeros((3, 2)), "confidence": np.array([0.9, 0.5, 0.25], np.float32),
        "axis_sigma_deg": np.array([0.5, 1.5, 4.0], np.float32), "rps_sigma_pct": np.array([0.4, 2.0, 6.0], np.float32)}
FRAME_T = np.array([10_500, 12_500, 14_000])


def _image(i: int) -> np.ndarray:
    yy, xx = np.mgrid[0:24, 0:32]
    return np.stack([xx * 7, yy * 9, np.full_like(xx, 60 * i)], axis=-1).astype(np.uint8)


def _ffmpeg() -> str | None:
    try:
        import imageio_ffmpeg
    except ImportError:
        return None
    return imageio_ffmpeg.get_ffmpeg_exe()


def _write_video(path: Path, codec: str) -> None:
    """The three test images as an MP4: ``mp4v`` with OpenCV, ``h264`` with imageio-ffmpeg's ffmpeg."""
    if codec == "h264":
        frames = np.stack([_image(i) for i in range(3)])
        subprocess.run([_ffmpeg(), "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
                        "-s", "32x24", "-r", "30", "-i", "-", "-c:v", "libx264", "-pix_fmt", "yuv420p",
                        str(path)], input=frames.tobytes(), check=True, timeout=60)
        return
    video = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), 30, (32, 24))
    for i in range(3):
        video.write(cv2.cvtColor(_image(i), cv2.COLOR_RGB2BGR))
    video.release()


def _make_session(path: Path, *, frames: str = "images", calibrated: bool = True) -> Path:
    """A small session; ``frames`` is "images", "none", or a video codec ("mp4v", "h264")."""
    attrs = {"calibration": {"homography": np.linalg.inv(H_FRAME_FROM_EVENT).tolist()}} if calibrated else {}
    with create_session(path, width=64, height=48, attrs=attrs) as w:
        w.append_events(_events())
        w.append_triggers(make_triggers([10_100, 15_100], [0, 0], [1, 0]))
        w.write_track(_track())
        w.write_spin(SPIN)
        if frames == "images":
            w.append_frames(FRAME_T, np.stack([_image(i) for i in range(3)]))
        elif frames != "none":
            _write_video(path / "gopro.mp4", frames)
            w.set_video("gopro.mp4", FRAME_T)
    return path


def read_rrd(path) -> dict:
    """entity -> component -> list of (t_us or None for static, value) in time order."""
    out: dict = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch()
        names = rb.schema.names
        if review.TIMELINE in names:
            assert rb.schema.field(review.TIMELINE).type == pa.duration("ns")
            t = list(rb.column(review.TIMELINE).cast(pa.int64()).to_numpy() // 1000)
        else:
            t = [None] * rb.num_rows
        for name in names:
            if name.startswith("rerun.") or name == review.TIMELINE:
                continue
            out[chunk.entity_path][name].extend(zip(t, rb.column(name).to_pylist()))
    for comps in out.values():
        for rows in comps.values():
            rows.sort(key=lambda row: -1 if row[0] is None else row[0])
    return out


def _temporal(rows):
    return [(t, v) for t, v in rows if t is not None]


def _texts(data) -> list[str]:
    return [text for _, row in data["/log"]["TextLog:text"] for text in row]


def _on_ball(events: np.ndarray) -> np.ndarray:
    """Events within 1.25 radii of the track's circle at their time."""
    cx, cy, r, valid = _track().circles_at(events["t"])
    return valid & (np.hypot(events["x"] - cx, events["y"] - cy) <= 1.25 * np.nan_to_num(r))


def _expected_logged(events: np.ndarray, *, ball_apart: bool = True) -> int:
    """All the ball's events (fewer than the ball's cap per slice) and the others thinned to CAP by a
    stride; without ``ball_apart`` (the live review, which has no track in advance) all thinned alike."""
    ball = _on_ball(events) if ball_apart else np.zeros(len(events), bool)
    _, counts = np.unique(events["t"][~ball] // SLICE_US, return_counts=True)
    return int(ball.sum()) + int(np.sum(-(-counts // -(-counts // CAP))))


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("review")
    session = _make_session(tmp / "session")
    stats = review.write_rrd(session, tmp / "out.rrd", slice_us=SLICE_US, max_events_per_slice=CAP,
                             batch_events=777, progress=False)
    return session, tmp / "out.rrd", stats, read_rrd(tmp / "out.rrd")


def test_one_recording_with_blueprint_and_timeline(written):
    session, rrd, _, data = written
    reader = RrdReader(rrd)
    (rec,) = reader.recordings()
    assert rec.application_id == review.APPLICATION_ID
    assert rec.recording_id == review.session_recording_id(open_session(session))
    assert len(reader.blueprints()) == 1
    for entity in ("/events/on", "/events/off", "/events/ball", "/frames/image", "/frames/ball",
                   "/ball3d/axis", "/ball3d/sphere", "/plots/rps", "/plots/axis/azimuth_deg",
                   "/plots/axis/elevation_deg", "/plots/confidence", "/plots/event_rate/events_ev_s"):
        assert entity in data, entity
    temporal = [c for c in reader.stream() if not c.is_static]
    assert temporal and all(c.timeline_names == [review.TIMELINE] for c in temporal)


def test_flight_table_as_a_text_view_and_colour_blind_safe_polarities(written):
    session, _, _, data = written
    (text,) = [v for _, row in data["/results/flights"]["TextDocument:text"] for v in ([row] if isinstance(row, str) else row)]
    from capture.results import flight_table, format_flight_table

    s = open_session(session)
    assert text == "```\n" + format_flight_table(flight_table(Track.from_columns(s.track()), s.spin())) + "\n```"
    assert "yield:" in text
    # sky blue and orange (Okabe-Ito): apart for red-green colour blindness, unlike green and red
    on = data["/events/on"]["Points2D:colors"][0][1]
    off = data["/events/off"]["Points2D:colors"][0][1]
    rgba = lambda c: [(c >> s_) & 255 for s_ in (24, 16, 8)]  # noqa: E731
    assert rgba(on[0]) == list(review.layout.ON_COLOR) == [86, 180, 233]
    assert rgba(off[0]) == list(review.layout.OFF_COLOR) == [230, 159, 0]


def test_events_sliced_split_by_polarity_and_decimated_by_stride(written):
    _, _, stats, data = written
    events = _events()
    on = _temporal(data["/events/on"]["Points2D:positions"])
    off = _temporal(data["/events/off"]["Points2D:positions"])
    logged = sum(len(v) for _, v in on) + sum(len(v) for _, v in off)
    assert logged == stats.n_events_logged == _expected_logged(events)
    assert stats.n_events == len(events) and stats.n_slices == 3 and stats.n_slices_decimated == 2
    # The undecimated first slice is logged exactly, at its start time, ON and OFF apart.
    first = events[events["t"] < 11_000]
    for rows, pol in ((on, 1), (off, 0)):
        t, xy = rows[0]
        assert t == 10_000
        sel = first[first["p"] == pol]
        np.testing.assert_array_equal(np.array(xy), np.c_[sel["x"], sel["y"]] + review.PIXEL_OFFSET)
    # The decimated second slice keeps every event on the ball and every k-th of the others.
    second = events[(events["t"] >= 11_000) & (events["t"] < 12_000)]
    ball = _on_ball(second)
    k = -(-np.count_nonzero(~ball) // CAP)
    keep = ball.copy()
    keep[np.flatnonzero(~ball)[::k]] = True
    assert 50 < ball.sum() < CAP and k >= 2  # the ball's events are not thinned with the rest
    t, xy = on[1]
    assert t == 11_000
    sel = second[keep & (second["p"] == 1)]
    np.testing.assert_array_equal(np.array(xy), np.c_[sel["x"], sel["y"]] + review.PIXEL_OFFSET)
    # The first empty slice clears the points.
    assert (12_000, []) in on and (12_000, []) in off
    assert any("decimated" in text for text in _texts(data))


def test_event_rate_per_slice_before_decimation(written):
    _, _, _, data = written
    rate = dict((t, v[0]) for t, v in _temporal(data["/plots/event_rate/events_ev_s"]["Scalars:scalars"]))
    assert rate == {10_000: 300_000.0, 11_000: 1_200_000.0, 12_000: 0.0, 15_000: 700_000.0}


def test_ball_circle_follows_track_and_clears_after_flight(written):
    _, _, _, data = written
    track = _track()
    centers = dict(_temporal(data["/events/ball"]["Ellipses2D:centers"]))
    sizes = dict(_temporal(data["/events/ball"]["Ellipses2D:half_sizes"]))
    for i in (0, 3, 8):
        t = int(track.t_us[i])
        np.testing.assert_allclose(centers[t][0], [track.cx[i] + 0.5, track.cy[i] + 0.5], rtol=1e-6)
        np.testing.assert_allclose(sizes[t][0], [track.r[i], track.r[i]])
    delay = 2 * 500  # twice the track step (500 µs) = SLICE_US here
    assert [t for t, _ in _temporal(data["/events/ball"]["Clear:is_recursive"])] == [13_000 + delay, 16_000 + delay]
    # the spin axis (3D and on the image) is cleared with the ball after each flight
    for entity in ("/ball3d/axis", "/events/spin_axis", "/events/spin_pole"):
        assert [t for t, _ in _temporal(data[entity]["Clear:is_recursive"])] == [13_000 + delay, 16_000 + delay]
    # the image speed from the track
    speed = dict((t, v[0]) for t, v in _temporal(data["/plots/speed/image_px_s"]["Scalars:scalars"]))
    assert speed[10_000] == pytest.approx(4000.0)
    # the circle's uncertainty, where measured
    sigma = _temporal(data["/plots/uncertainty/ball_px"]["Scalars:scalars"])
    assert [t for t, _ in sigma] == list(track.t_us[2:])
    np.testing.assert_allclose([v[0] for _, v in sigma], np.linspace(0.2, 1.6, 8), rtol=1e-6)


def test_two_balls_in_view_at_once_both_shown_each_spin_on_its_own(tmp_path):
    t0, t1 = np.arange(10_000, 13_001, 500), np.arange(10_250, 12_751, 500)
    track = Track(t_us=np.r_[t0, t1], cx=np.r_[10.0 + 0.004 * (t0 - 10_000), 50.0 - 0.004 * (t1 - 10_000)],
                  cy=np.r_[np.full(len(t0), 20.0), np.full(len(t1), 35.0)], r=np.r_[np.full(len(t0), 8.0),
                  np.full(len(t1), 6.0)], vx=np.r_[np.full(len(t0), 4000.0), np.full(len(t1), -4000.0)],
                  vy=np.zeros(len(t0) + len(t1)), score=np.ones(len(t0) + len(t1)),
                  flight=np.r_[np.zeros(len(t0), int), np.ones(len(t1), int)])
    track = track.select(np.argsort(track.t_us, kind="stable"))
    spin = {k: v[:2] for k, v in SPIN.items()}
    spin.update(t_start_us=np.array([11_000, 11_000]), t_end_us=np.array([12_000, 12_000]), flight=np.array([1, 0]),
                axis=np.array([[1.0, 0, 0], [0, 1.0, 0]]))
    with create_session(tmp_path / "s", width=64, height=48) as w:
        w.append_events(_events())
        w.write_track(track)
        w.write_spin(spin)
    review.write_rrd(tmp_path / "s", tmp_path / "two.rrd", slice_us=SLICE_US, progress=False)
    data = read_rrd(tmp_path / "two.rrd")
    centers = dict(_temporal(data["/events/ball"]["Ellipses2D:centers"]))
    for t in (10_500, 10_750):  # a row of one flight: both balls drawn, each where its track puts it
        expected = [[np.interp(t, t0, 10.0 + 0.004 * (t0 - 10_000)) + 0.5, 20.5],
                    [np.interp(t, t1, 50.0 - 0.004 * (t1 - 10_000)) + 0.5, 35.5]]
        np.testing.assert_allclose(sorted(centers[t], key=lambda c: c[1]), expected, rtol=1e-6)
    assert len(centers[13_000]) == 1  # the second ball's flight has ended
    # each window's axis is drawn on its own ball (the flight column), not on the first one in view
    origins = [np.array(v) for _, v in _temporal(data["/events/spin_axis"]["Arrows2D:origins"])]
    assert [round(o[0][1]) for o in origins] == [36, 20]  # window 0 on flight 1 (cy 35), window 1 on flight 0


def test_spin_series_and_axis(written):
    _, _, _, data = written
    mid = (SPIN["t_start_us"] + SPIN["t_end_us"]) // 2

    def series(entity):
        rows = _temporal(data[entity]["Scalars:scalars"])
        assert [t for t, _ in rows] == list(mid)
        return np.array([v[0] for _, v in rows])

    np.testing.assert_allclose(series("/plots/rps"), SPIN["rps"])
    np.testing.assert_allclose(series("/plots/confidence"), SPIN["confidence"], rtol=1e-6)
    np.testing.assert_allclose(series("/plots/uncertainty/rps_pct"), SPIN["rps_sigma_pct"], rtol=1e-6)
    np.testing.assert_allclose(series("/plots/uncertainty/axis_deg"), SPIN["axis_sigma_deg"], rtol=1e-6)
    np.testing.assert_allclose(series("/plots/axis/azimuth_deg"), [90.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(series("/plots/axis/elevation_deg"),
                               [0.0, 90.0, np.degrees(np.arcsin(-0.6))], atol=1e-9)
    vectors = [np.array(v[0]) for _, v in _temporal(data["/ball3d/axis"]["Arrows3D:vectors"])]
    for vec, axis in zip(vectors, SPIN["axis"]):
        np.testing.assert_allclose(vec / np.linalg.norm(vec), axis, atol=1e-6)
    # rpm split by trust: windows 0 and 1 trusted (confidence >= 0.5), window 2 not
    trusted = _temporal(data["/plots/rpm/trusted"]["Scalars:scalars"])
    untrusted = _temporal(data["/plots/rpm/not_trusted"]["Scalars:scalars"])
    assert [(t, v[0]) for t, v in trusted] == [(int(mid[0]), 600.0), (int(mid[1]), 1200.0)]
    assert [(t, v[0]) for t, v in untrusted] == [(int(mid[2]), 60 * 30.5)]
    # components in the flight's frame (no image velocity: the flight is taken along +X, up -Y)
    np.testing.assert_allclose(series("/plots/spin/gyro_rpm"), [600.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(series("/plots/spin/sidespin_rpm"), [0.0, 1200.0, -0.6 * 60 * 30.5], atol=1e-9)
    np.testing.assert_allclose(series("/plots/spin/topspin_rpm"), [0.0, 0.0, -0.8 * 60 * 30.5], atol=1e-9)
    labels = [v[0] for _, v in _temporal(data["/ball3d/axis"]["Arrows3D:labels"])]
    assert labels == ["600 rpm ±0.4 %", "1200 rpm ±2.0 %", "not trusted (0.25)"]
    colors = [v[0] for _, v in _temporal(data["/ball3d/axis"]["Arrows3D:colors"])]
    rgb = lambda c: [(c >> s_) & 255 for s_ in (24, 16, 8)]  # noqa: E731
    assert [rgb(c) for c in colors] == [list(review.layout.AXIS_COLOR)] * 2 + [list(review.layout.UNTRUSTED_COLOR)]
    # the trust threshold across the spin windows
    trust = [(t, v[0]) for t, v in _temporal(data["/plots/confidence/trust"]["Scalars:scalars"])]
    assert trust == [(int(mid[0]), 0.5), (int(mid[-1]), 0.5)]


def test_the_axis_pole_on_the_cameras_side_shows_where_the_axis_points(written):
    """An axis toward or away from the camera projects to a short arrow; its pole on the camera's
    side of the ball is drawn as a dot, so it is seen on the ball."""
    _, _, _, data = written
    mid = (SPIN["t_start_us"] + SPIN["t_end_us"]) // 2
    poles = dict(_temporal(data["/events/spin_pole"]["Points2D:positions"]))
    track = _track()
    cx, cy, r, _ = track.circles_at(mid)
    for i, axis in enumerate(SPIN["axis"]):
        pole = axis if axis[2] <= 0 else -axis  # window 2's axis (0, 0.6, 0.8) points away: its -axis end shows
        np.testing.assert_allclose(poles[int(mid[i])][0], [cx[i] + 0.5 + pole[0] * r[i], cy[i] + 0.5 + pole[1] * r[i]],
                                   rtol=1e-5)
    colors = dict(_temporal(data["/events/spin_pole"]["Points2D:colors"]))
    rgb = lambda c: [(c >> s_) & 255 for s_ in (24, 16, 8)]  # noqa: E731
    assert rgb(colors[int(mid[2])][0]) == list(review.layout.UNTRUSTED_COLOR)  # not trusted: grey


def test_flights_marked_on_the_plots_and_in_the_log(written):
    _, _, _, data = written
    from capture.results import flight_table

    table = flight_table(_track(), SPIN)
    flight = [(t, v[0]) for t, v in _temporal(data["/plots/rpm/flight"]["Scalars:scalars"])]
    # flight 0: its rate from its first to its last track row, then a break; flight 1 has no trusted window
    assert flight[:2] == [(10_000, table["rpm"][0]), (13_000, table["rpm"][0])] and np.isnan(flight[2][1])
    assert len(flight) == 3
    texts = _texts(data)
    assert any(t.startswith("flight 0 starts: 900 ± ") for t in texts)
    assert any(t.startswith("flight 1 starts: no trusted estimate") for t in texts)
    assert "flight 1 ends (1 ms)" in texts


def test_a_flight_with_a_rate_but_no_trusted_axis_says_so_in_the_log(tmp_path):
    """Flight 1's one window is not trusted and its rate (30.5 rps) singles out no fold of the period the
    analysis stored (0.1 s); the whole flight's spin, not trusted but sure of its fold, gives the turn: the
    log gives the rate from the image's period and says the axis is not trusted."""
    from capture.results import PERIOD_SIGMA_REPEATS_PCT
    from capture.session import update_session

    session = _make_session(tmp_path / "session", frames="none")
    w = update_session(session)
    w.set_attrs(flight_periods={"0": None, "1": [0.1, 0.6, 0.35]},
                flight_spins={"1": {"axis": [0.0, 0.0, -1.0], "omega_rad_s": 2 * np.pi * 10.0, "fold": 1, "ratio": 2.0,
                                    "excess": 30.0, "trusted": False, "axis_sigma_deg": 1.8, "rps_sigma_pct": 0.7,
                                    "turns": 3.5, "fold_ratio": 1.8, "rate_trusted": True}})
    w.close()
    review.write_rrd(session, tmp_path / "out.rrd", slice_us=SLICE_US, max_events_per_slice=CAP, progress=False)
    texts = _texts(read_rrd(tmp_path / "out.rrd"))
    sigma = 600.0 * PERIOD_SIGMA_REPEATS_PCT * 0.1 / 0.35 / 100.0  # over the 3.5 repeats
    assert f"flight 1 starts: no trusted axis, 600 ± {sigma:.0f} rpm from the image's period, 0/1 windows trusted" in texts


def _blueprint(rrd) -> dict:
    """Blueprint entity -> component -> value of the review's blueprint."""
    reader = RrdReader(rrd)
    out = defaultdict(dict)
    for chunk in reader.stream(store=reader.blueprints()[0]):
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if ":" in name:
                out[str(chunk.entity_path)][name] = rb.column(name).to_pylist()[0]
    return out


def test_the_viewer_opens_on_the_first_flight_with_the_side_panels_folded(written):
    _, rrd, _, _ = written
    bp = _blueprint(rrd)
    time_panel = bp["/time_panel"]
    assert time_panel["TimePanelBlueprint:time_selection"] == [{"min": 10_000_000, "max": 13_000_000}]  # ns
    assert time_panel["TimePanelBlueprint:playback_speed"] == [0.1]
    assert bp["/blueprint_panel"]["PanelBlueprint:state"] == bp["/selection_panel"]["PanelBlueprint:state"]
    names = {v[0] for e in bp.values() for k, v in e.items() if k.endswith(":display_name") and v}
    assert {"Events", "GoPro", "Spin axis", "Spin (rpm)", "Speed", "Flights"} <= names
    assert max(map(len, names)) <= 30  # titles short enough for a 1366 px wide screen


def test_frames_as_images_with_mapped_circle(written):
    _, _, stats, data = written
    blobs = _temporal(data["/frames/image"]["EncodedImage:blob"])
    assert [t for t, _ in blobs] == list(FRAME_T) and stats.n_frames == 3
    decoded = cv2.cvtColor(cv2.imdecode(np.frombuffer(bytes(blobs[1][1][0]), np.uint8), cv2.IMREAD_COLOR),
                           cv2.COLOR_BGR2RGB)
    assert np.abs(decoded.astype(int) - _image(1)).mean() < 4
    circles = dict(_temporal(data["/frames/ball"]["Ellipses2D:centers"]))
    sizes = dict(_temporal(data["/frames/ball"]["Ellipses2D:half_sizes"]))
    cx, cy, r, _, _ = _track().at(12_500)
    np.testing.assert_allclose(circles[12_500][0], [0.5 * cx + 3 + 0.5, 0.5 * cy + 4 + 0.5], rtol=1e-6)
    np.testing.assert_allclose(sizes[12_500][0], [0.5 * r, 0.5 * r], rtol=1e-6)
    assert circles[14_000] == []  # no ball between flights


def test_frames_without_calibration_say_why_they_have_no_ball_circle(written, tmp_path):
    _, _, _, data = written
    assert "/frames/note" not in data  # calibrated: circles, no note
    session = _make_session(tmp_path / "session", calibrated=False)
    review.write_rrd(session, tmp_path / "n.rrd", progress=False)
    plain = read_rrd(tmp_path / "n.rrd")
    (label,) = plain["/frames/note"]["Points2D:labels"][0][1]
    assert "not calibrated" in label and _temporal(plain["/frames/ball"]["Ellipses2D:centers"]) == []
    assert any("no calibration between the event camera and the GoPro" in t for t in _texts(plain))


def test_streaming_batch_size_does_not_change_result(written, tmp_path):
    session, _, stats, _ = written
    again = review.write_rrd(session, tmp_path / "big.rrd", slice_us=SLICE_US, max_events_per_slice=CAP,
                             batch_events=1 << 20, progress=False)
    assert (again.n_events, again.n_events_logged, again.n_slices) == \
        (stats.n_events, stats.n_events_logged, stats.n_slices)


# The MP4 inside the session directory makes Zarr warn when it consolidates the metadata.
@pytest.mark.filterwarnings("ignore:Object at gopro.mp4 is not recognized")
def test_video_that_rerun_cannot_decode_falls_back_to_images(tmp_path):
    session = _make_session(tmp_path / "session", frames="mp4v")
    stats = review.write_rrd(session, tmp_path / "v.rrd", progress=False)
    data = read_rrd(tmp_path / "v.rrd")
    assert [t for t, _ in _temporal(data["/frames/image"]["EncodedImage:blob"])] == list(FRAME_T)
    assert stats.n_frames == 3
    assert any("not embedded" in text for text in _texts(data))


@pytest.mark.filterwarnings("ignore:Object at gopro.mp4 is not recognized")
def test_h264_video_is_embedded_and_referenced(tmp_path):
    if _ffmpeg() is None:
        pytest.skip("imageio-ffmpeg (an H.264 encoder) is not installed")
    session = _make_session(tmp_path / "session", frames="h264")
    stats = review.write_rrd(session, tmp_path / "v.rrd", progress=False)
    data = read_rrd(tmp_path / "v.rrd")
    refs = _temporal(data["/frames/image"]["VideoFrameReference:timestamp"])
    assert [t for t, _ in refs] == list(FRAME_T) and stats.n_frames == 3
    assert [v for _, v in refs] == [[0], [33_333_333], [66_666_667]]  # the MP4's own frame times, ns
    assert len(data["/video/asset"]["AssetVideo:blob"]) == 1
    assert bytes(data["/video/asset"]["AssetVideo:blob"][0][1][0]) == (session / "gopro.mp4").read_bytes()


def test_bad_inputs_give_clear_errors(tmp_path):
    with pytest.raises(SessionError, match="no such session directory"):
        review.write_rrd(tmp_path / "missing", tmp_path / "x.rrd", progress=False)
    (tmp_path / "plain").mkdir()
    with pytest.raises(SessionError, match="not a session"):
        review.write_rrd(tmp_path / "plain", tmp_path / "x.rrd", progress=False)
    session = _make_session(tmp_path / "session", frames="none")
    with pytest.raises(review.ReviewError, match="is a directory"):
        review.write_rrd(session, tmp_path, progress=False)
    with pytest.raises(review.ReviewError, match="max_events_per_slice"):
        review.write_rrd(session, tmp_path / "x.rrd", max_events_per_slice=0, progress=False)


def test_cli(tmp_path, capsys):
    session = _make_session(tmp_path / "session", frames="none")
    assert main([str(session), "--rrd", str(tmp_path / "cli.rrd"), "--quiet"]) == 0
    assert "1200" not in capsys.readouterr().err and RrdReader(tmp_path / "cli.rrd").recordings()
    proc = subprocess.run([sys.executable, "-m", "capture.review", str(tmp_path / "nope"), "--rrd",
                           str(tmp_path / "n.rrd")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stderr.strip().count("\n") == 0 and "no such session directory" in proc.stderr


def test_live_review_rrd_mode_writes_same_layout(tmp_path):
    events = _events(seed=1)
    estimate = SimpleNamespace(**{k: (v[2] if k != "axis" else v[2].copy()) for k, v in SPIN.items()})
    with review.LiveReview("rrd", rrd_path=tmp_path / "live.rrd", width=64, height=48, recording_id="rec-1",
                           slice_us=SLICE_US, max_events_per_slice=CAP) as live:
        for part in np.array_split(events, 4):
            live.log_events(part)
        live.log_track(_track())
        live.log_spin(estimate)
        live.log_frame(14_500, _image(2))
        live.log_status(15_500, drops=3, event_rate_ev_s=1.5e6)
        live.log_message("hello")
    assert live.skipped == {} and live.error is None
    (rec,) = RrdReader(tmp_path / "live.rrd").recordings()
    assert rec.recording_id == "rec-1"
    data = read_rrd(tmp_path / "live.rrd")
    logged = sum(len(v) for e in ("/events/on", "/events/off")
                 for _, v in _temporal(data[e]["Points2D:positions"]))
    assert logged == live.stats.n_events_logged == _expected_logged(events, ball_apart=False)
    assert _temporal(data["/plots/status/drops"]["Scalars:scalars"]) == [(15_500, [3.0])]
    assert _temporal(data["/plots/rps"]["Scalars:scalars"]) == [(15_500, [30.5])]
    assert [t for t, _ in _temporal(data["/frames/image"]["EncodedImage:blob"])] == [14_500]
    assert "hello" in [text for text in _texts(data)]
    # the 2D spin axis sits on the ball centre at the estimate's time
    origin = _temporal(data["/events/spin_axis"]["Arrows2D:origins"])[0]
    cx, cy, _, _, _ = _track().at(15_500)
    np.testing.assert_allclose(origin[1][0], [cx + 0.5, cy + 0.5], rtol=1e-6)


def test_live_review_skips_instead_of_blocking(tmp_path, monkeypatch):
    gate, busy = threading.Event(), threading.Event()
    handle = review.LiveReview._handle

    def slow_handle(self, kind, payload):
        busy.set()
        gate.wait(10)
        handle(self, kind, payload)

    monkeypatch.setattr(review.LiveReview, "_handle", slow_handle)
    live = review.LiveReview("rrd", rrd_path=tmp_path / "s.rrd", max_queue=1, slice_us=SLICE_US)
    events = _events()
    live.log_events(events[:100])
    assert busy.wait(10)  # the thread now holds the first batch
    live.log_events(events[100:200])  # fills the queue
    live.log_events(events[200:300])  # skipped, returns at once
    live.log_status(11_000, drops=1)  # skipped
    assert live.skipped == {"events": 1, "status": 1}
    gate.set()
    live.close()
    data = read_rrd(tmp_path / "s.rrd")
    assert live.stats.n_events == 200
    assert any("skipped" in text for text in _texts(data))


def test_live_review_none_costs_nothing():
    before = threading.active_count()
    live = review.LiveReview("none")
    live.log_events(_events())
    live.log_status(0, drops=1)
    live.close()
    assert live.stats is None and threading.active_count() == before


def test_live_review_serve_mode_gives_url():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    live = review.LiveReview("serve", grpc_port=port, width=64, height=48)
    live.log_status(1000, drops=2)
    live.close()
    assert live.url == f"rerun+http://127.0.0.1:{port}/proxy" and live.error is None


def test_live_review_bad_arguments():
    with pytest.raises(review.ReviewError, match="viewer mode"):
        review.LiveReview("window")
    with pytest.raises(review.ReviewError, match="rrd_path"):
        review.LiveReview("rrd")


def test_axis_angles_and_track_circles_at():
    az, el = review.axis_angles_deg([[0, 0, 1], [1, 0, 0], [0, -1, 0], [-1, 0, 0]])
    np.testing.assert_allclose(az, [0, 90, 0, -90], atol=1e-9)
    np.testing.assert_allclose(el, [0, 0, 90, 0], atol=1e-9)
    track = _track()
    cx, cy, r, valid = track.circles_at([10_250, 14_000, 15_500, 20_000])
    np.testing.assert_array_equal(valid, [True, False, True, False])
    np.testing.assert_allclose([cx[0], cy[0], r[0]], track.at(10_250)[:3])
    np.testing.assert_allclose([cx[2], cy[2], r[2]], track.at(15_500)[:3])


def test_live_review_reports_spin_without_its_columns(tmp_path):
    with review.LiveReview("rrd", rrd_path=tmp_path / "bad.rrd", slice_us=SLICE_US) as live:
        live.log_spin({"t_start_us": [0], "t_end_us": [1000]})
    assert isinstance(live.error, review.ReviewError) and "lack" in str(live.error)
