"""A shareable report of an analysed session: one self-contained HTML file.

:func:`write_html` writes the per-flight table (:mod:`capture.results`) and, for each flight,
plots embedded as PNG (matplotlib, no network and no script needed to view it): the spin rate of
every window over time with its uncertainty (trusted windows filled, the others hollow and grey,
the flight's value drawn across), the topspin / sidespin / gyro components, and the ball's events
of the flight's most confident window as recorded beside the same events turned back by the
estimated spin (a sharp texture means the spin is right), with the axis drawn. One more plot
shows the track on the sensor.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from capture.events import Track
from capture.results import TRUST

_COLUMNS = [("flight", "flight", "{}"), ("ball", "ball", "{}"), ("t_start_s", "start (s)", "{:.3f}"), ("duration_ms", "duration (ms)", "{:.0f}"),
            ("n_trusted", "trusted windows", "{}"), ("n_windows", "windows", "{}"), ("rpm", "rpm", "{:.0f}"),
            ("rpm_sigma", "± rpm (1σ)", "{:.0f}"), ("topspin_rpm", "topspin rpm", "{:.0f}"),
            ("sidespin_rpm", "sidespin rpm", "{:.0f}"), ("gyro_rpm", "gyro rpm", "{:.0f}"),
            ("efficiency", "efficiency", "{:.0%}"), ("tilt", "tilt", "{}"),
            ("axis_sigma_deg", "axis ± deg (1σ)", "{:.1f}"), ("image_speed_px_s", "image speed (px/s)", "{:.0f}"),
            ("distance_m", "distance (m)", "{:.1f}"), ("speed_km_h", "3D speed (km/h)", "{:.1f}"),
            ("speed_sigma_m_s", "± m/s (1σ)", "{:.2f}"), ("period_rpm", "period rpm", "{:.0f}"),
            ("period_rpm_sigma", "± rpm (1σ)", "{:.0f}"), ("period_fold_from", "period's turn from", "{}"),
            ("period_contradicts", "contradicted by the period", "{}")]


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _cell(fmt: str, v) -> str:
    if isinstance(v, float) and not np.isfinite(v):
        return "–"
    try:
        return html.escape(fmt.format(v))
    except (TypeError, ValueError):
        return html.escape(str(v))


def _table(flights: dict) -> str:
    head = "".join(f"<th>{html.escape(name)}</th>" for _, name, _ in _COLUMNS)
    rows = []
    for i in range(len(flights["flight"])):
        cells = "".join(f"<td>{_cell(fmt, flights[k][i].item() if hasattr(flights[k][i], 'item') else flights[k][i])}"
                        "</td>" for k, _, fmt in _COLUMNS)
        rows.append(f"<tr>{cells}</tr>")
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def _spin_plot(win: dict, sel: np.ndarray, fl_row: dict) -> str:
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.2))
    t = 0.5 * (win["t_start_s"][sel] + win["t_end_s"][sel])
    rpm, ok = win["rpm"][sel], win["trusted"][sel]
    err = win["rpm"][sel] * np.nan_to_num(win["rps_sigma_pct"][sel]) / 100.0
    a.errorbar(t[ok], rpm[ok], yerr=err[ok], fmt="o", color="#0072B2", label=f"trusted (confidence ≥ {TRUST})")
    a.plot(t[~ok], rpm[~ok], "o", mfc="none", color="#999999", label="not trusted")
    if np.isfinite(fl_row["rpm"]):
        a.axhline(fl_row["rpm"], color="#D55E00", lw=1, label=f"flight: {fl_row['rpm']:.0f} ± {fl_row['rpm_sigma']:.0f} rpm")
    a.set_xlabel("time (s, event clock)")
    a.set_ylabel("spin (rpm)")
    a.legend(fontsize=8)
    a.set_title("spin rate per window")
    for key, colour in (("topspin_rpm", "#0072B2"), ("sidespin_rpm", "#E69F00"), ("gyro_rpm", "#009E73")):
        b.plot(t[ok], win[key][sel][ok], "o-", color=colour, ms=4, label=key.replace("_rpm", ""))
    b.axhline(0, color="k", lw=0.5)
    b.set_xlabel("time (s, event clock)")
    b.set_ylabel("rpm")
    b.legend(fontsize=8)
    b.set_title("spin in the flight's frame (trusted windows)")
    return _png(fig)


def _ball_images(session, track: Track, spin: dict, i: int, flight: int) -> str | None:
    """Events of window ``i`` as recorded and turned back by its estimated spin, axis drawn."""
    import matplotlib.pyplot as plt

    from capture.pipeline.ball_view import ball_view

    view = ball_view(session, track, spin, i, flight=flight)
    if view is None:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(7, 3.6))
    lim, r = view.half_px, view.r_px
    for ax, h, title in ((axes[0], view.recorded, "ball events as recorded"),
                         (axes[1], view.turned, f"turned back by {spin['rps'][i] * 60:.0f} rpm")):
        ax.imshow(h, cmap="magma", extent=(-lim, lim, lim, -lim), interpolation="nearest")
        ax.add_patch(plt.Circle((0, 0), r, fill=False, color="#56B4E9", lw=0.8))
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    ax_x, ax_y, ax_z = view.axis
    axes[1].annotate("", xy=(ax_x * r, ax_y * r), xytext=(0, 0),
                     arrowprops=dict(arrowstyle="->", color="#F0E442", lw=2))
    axes[1].text(0.02, 0.02, f"axis ({ax_x:+.2f}, {ax_y:+.2f}, {ax_z:+.2f})", color="w", fontsize=8,
                 transform=axes[1].transAxes)
    return _png(fig)


def _track_plot(track: Track, width: int, height: int) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6 * height / max(width, 1) + 0.4))
    for fl in track.flight_ids():
        sel = track.flight == fl
        ax.plot(track.cx[sel], track.cy[sel], ".-", ms=3, label=f"flight {int(fl)}")
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    ax.set_title("ball track on the event sensor")
    if len(track):
        ax.legend(fontsize=8)
    return _png(fig)


def write_html(session_path, out_path, *, ball_diameter_m: float | None = None, ball_type: str | None = None) -> Path:
    """Write the report of an analysed session to ``out_path`` (one HTML file, images inside).

    ``ball_diameter_m`` and ``ball_type`` as for :func:`capture.pipeline.replay.session_results`
    (default: the ball recorded with the session).

    Raises
    ------
    ValueError
        The session holds no track (not analysed yet).
    """
    import matplotlib

    matplotlib.use("Agg")
    from capture.results import session_results, stored_ball
    from capture.session import open_session

    s = open_session(session_path)
    if "track" not in s.root:
        raise ValueError(f"{session_path}: not analysed yet (no ball track); run: python -m capture.replay "
                         f"{session_path}")
    track = Track.from_columns(s.track())
    spin = s.spin()
    flights, win = session_results(s, ball_diameter_m=ball_diameter_m, ball_type=ball_type)
    parts = [f"<h1>Session {html.escape(Path(session_path).name)}</h1>",
             f"<p>{s.width}x{s.height} sensor, recorded {html.escape(str(s.attrs.get('created_utc', '?')))}, "
             f"software {html.escape(str(s.attrs.get('software_version', '?')))}. "
             f"{len(flights['flight'])} flight(s), {int(np.isfinite(flights['rpm'].astype(float)).sum())} with a "
             "trusted spin.</p>",
             _table(flights),
             *(["<p class='note'>The session has no calibration of the event camera: no distances or speeds "
                "(calib.store_calibration).</p>"]
               if len(flights["flight"]) and (ball_diameter_m or stored_ball(s)[1])
               and np.isnan(flights["speed_m_s"].astype(float)).all()
               else []),
             "<p class='note'>rpm: median of the trusted windows (confidence ≥ 0.5) ± its standard error. Topspin "
             "(&gt; 0) / backspin (&lt; 0), sidespin (&gt; 0: counter-clockwise seen from above) and gyro spin "
             "are in the flight's frame (direction of flight = the image velocity, up = the image's up). "
             "Efficiency: the share of spin that bends the flight. Tilt: the axis seen from behind the ball, "
             "12:00 backspin, 3:00 sidespin, 6:00 topspin.</p>",
             f"<img alt='track' src='{_track_plot(track, s.width, s.height)}'>"]
    for k, fl in enumerate(flights["flight"]):
        row = {key: flights[key][k] for key in flights}
        sel = win["flight"] == fl
        parts.append(f"<h2>Flight {int(fl)}</h2>")
        if not sel.any():
            parts.append("<p>No spin window in this flight.</p>")
            continue
        parts.append(f"<img alt='spin of flight {int(fl)}' src='{_spin_plot(win, sel, row)}'>")
        idx = np.flatnonzero(sel)
        best = idx[np.argmax(win["confidence"][idx])]
        img = _ball_images(s, track, spin, int(best), int(fl))
        if img:
            parts.append(f"<img alt='ball events of flight {int(fl)}' src='{img}'>"
                         f"<p class='note'>The flight's most confident window (confidence "
                         f"{win['confidence'][best]:.2f}): a sharp texture on the right means the spin fits.</p>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #bbb;padding:3px 6px;"
             "text-align:right}th{background:#eee}img{max-width:100%;display:block;margin:1em 0}.note{color:#555;"
             "font-size:13px}")
    doc = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>Session "
           f"{html.escape(Path(session_path).name)}</title><style>{style}</style></head><body>{''.join(parts)}"
           "</body></html>")
    out = Path(out_path)
    out.write_text(doc, encoding="utf-8")
    return out
