"""What each GoPro model accepts over the Open GoPro HTTP API (HERO9 to HERO13 Black).

Facts from the Open GoPro specification and its Python SDK (setting and status ids, model
numbers, per-model options):

- model numbers (``/gopro/camera/info`` ``model_number``): 55 HERO9, 57 HERO10, 58 HERO11,
  60 HERO11 Mini, 62 HERO12, 65 HERO13 Black;
- HERO9 Black cannot be controlled over USB (wired control needs HERO10 or later);
- anti-flicker (setting 134) takes 2 (60 Hz) / 3 (50 Hz) on HERO9–12 and 0 (NTSC, 60 Hz) /
  1 (PAL, 50 Hz) on HERO13;
- control mode (setting 175: 0 easy, 1 pro) exists from HERO11 on; the SDK sets "pro" before
  setting video options;
- ``set_date_time`` takes ``tzone`` / ``dst`` from HERO11 on; HERO9/10 take date and time only;
- a refused setting answers HTTP 403 with ``{"error", "setting_id", "option_id",
  "supported_options": [{"display_name", "id"}]}``.

:func:`nearest_option` picks, among the options a camera says it supports, the one closest to
what was asked (frame rate by frames per second, resolution by lines, anti-flicker by mains
frequency), so that a recording goes ahead with a said-so substitute instead of aborting.
"""

from __future__ import annotations

from dataclasses import dataclass, field

SETTING_RESOLUTION = 2
SETTING_FPS = 3
SETTING_AUTO_POWER_DOWN = 59
SETTING_VIDEO_LENS = 121
SETTING_ANTI_FLICKER = 134
SETTING_HYPERSMOOTH = 135
SETTING_CONTROL_MODE = 175

AUTO_POWER_DOWN_NEVER = 0
CONTROL_MODE_PRO = 1
HYPERSMOOTH_OFF = 0

PRESET_GROUP_VIDEO = 1000
PRESET_GROUP_PHOTO = 1001
PRESET_GROUP_TIMELAPSE = 1002

STATUS_BATTERY_PRESENT = 1
STATUS_OVERHEATING = 6
STATUS_BUSY = 8
STATUS_ENCODING = 10
STATUS_SD_STATUS = 33
STATUS_REMAINING_VIDEO_S = 35
STATUS_SD_REMAINING_KB = 54
STATUS_BATTERY_PCT = 70
STATUS_COLD = 85
STATUS_PRESET_GROUP = 96

SD_STATUS = {-1: "unknown", 0: "OK", 1: "full", 2: "removed", 3: "format error", 4: "busy", 8: "swapped"}
"""Status 33 (primary storage) values."""

RESOLUTION_OPTIONS = {"4K": 1, "2.7K": 4, "2.7K_4:3": 6, "1080": 9, "4K_4:3": 18, "5.3K": 100}
"""Video resolution (setting 2) options common to HERO10–13."""

RESOLUTION_LINES = {1: 2160, 4: 1520, 6: 2028, 9: 1080, 18: 2880, 100: 2988}
"""Vertical pixels of each resolution option (used to find the nearest one)."""

FPS_OPTIONS = {240: 0, 120: 1, 100: 2, 60: 5, 50: 6, 30: 8, 25: 9, 24: 10, 200: 13}
"""Frames per second (setting 3) options (the camera records 240 as 240000/1001, etc.)."""

LENS_OPTIONS = {"wide": 0, "narrow": 2, "superview": 3, "linear": 4, "linear_horizon_leveling": 8}
"""Video lens (setting 121) options."""

MAINS_HZ = ("50Hz", "60Hz")


@dataclass(frozen=True)
class CameraModel:
    """One camera model's answers to the HTTP API.

    Attributes
    ----------
    number : int
        ``model_number`` of ``/gopro/camera/info``.
    name : str
        Marketing name, e.g. ``"HERO12 Black"``.
    wired_control : bool
        Whether it can be controlled over its USB network.
    anti_flicker : dict[str, int]
        ``{"50Hz": option, "60Hz": option}`` of setting 134.
    control_mode : bool
        Whether setting 175 (control mode easy/pro) exists.
    date_time_zone : bool
        Whether ``set_date_time`` takes ``tzone`` and ``dst``.
    options : dict[int, tuple[int, ...]]
        Options of each setting the model accepts (the fake camera answers 403 to others).
    """

    number: int
    name: str
    wired_control: bool = True
    anti_flicker: dict = field(default_factory=lambda: {"60Hz": 2, "50Hz": 3})
    control_mode: bool = True
    date_time_zone: bool = True
    options: dict = field(default_factory=dict)

    def anti_flicker_option(self, mains: str) -> int:
        """Option of setting 134 for mains frequency ``"50Hz"`` or ``"60Hz"``."""
        if mains not in self.anti_flicker:
            raise ValueError(f"GoPro anti_flicker={mains!r} not supported; choose one of {list(MAINS_HZ)}")
        return self.anti_flicker[mains]


def _options(*, af: tuple[int, int], lens=(0, 2, 3, 4, 8), control_mode: bool, res=(1, 4, 6, 9, 18, 100)):
    out = {SETTING_RESOLUTION: res, SETTING_FPS: tuple(FPS_OPTIONS.values()), SETTING_VIDEO_LENS: lens,
           SETTING_ANTI_FLICKER: af, SETTING_HYPERSMOOTH: (0, 1, 2, 3, 4),
           SETTING_AUTO_POWER_DOWN: (0, 1, 4, 6, 7)}
    if control_mode:
        out[SETTING_CONTROL_MODE] = (0, 1)
    return out


MODELS = {
    55: CameraModel(55, "HERO9 Black", wired_control=False, control_mode=False, date_time_zone=False,
                    options=_options(af=(2, 3), control_mode=False)),
    57: CameraModel(57, "HERO10 Black", control_mode=False, date_time_zone=False,
                    options=_options(af=(2, 3), control_mode=False)),
    58: CameraModel(58, "HERO11 Black", options=_options(af=(2, 3), control_mode=True)),
    60: CameraModel(60, "HERO11 Black Mini", options=_options(af=(2, 3), control_mode=True)),
    62: CameraModel(62, "HERO12 Black", options=_options(af=(2, 3), control_mode=True)),
    65: CameraModel(65, "HERO13 Black", anti_flicker={"60Hz": 0, "50Hz": 1},
                    options=_options(af=(0, 1), control_mode=True)),
}
"""Known models by model number."""

UNKNOWN_MODEL = CameraModel(0, "unknown GoPro")
"""Used when the camera does not say its model: HERO10–12 answers, refusals handled by :func:`nearest_option`."""


def model_by_name(name: str) -> CameraModel:
    """A profile by a short name like ``"HERO13"`` or ``"hero11 mini"``.

    Raises
    ------
    ValueError
        For a name that matches no known model.
    """
    key = name.lower().replace(" ", "").replace("black", "")
    for m in MODELS.values():
        if m.name.lower().replace(" ", "").replace("black", "") == key:
            return m
    raise ValueError(f"unknown GoPro model {name!r}; known: {', '.join(m.name for m in MODELS.values())}")


def _fps_of(option: int) -> float | None:
    return next((float(f) for f, o in FPS_OPTIONS.items() if o == option), None)


def _mains_of(option: int) -> float | None:
    return {0: 60.0, 2: 60.0, 1: 50.0, 3: 50.0}.get(option)


_MEASURE = {SETTING_FPS: _fps_of, SETTING_RESOLUTION: RESOLUTION_LINES.get, SETTING_ANTI_FLICKER: _mains_of}


def nearest_option(setting_id: int, option: int, supported: list[int]) -> int | None:
    """The supported option closest to ``option`` (``None`` when there is no meaningful one).

    Frame rates compare by frames per second (a tie goes to the higher rate), resolutions by
    lines, anti-flicker by mains frequency; for other settings only an exact match counts.
    """
    if option in supported:
        return option
    measure = _MEASURE.get(setting_id)
    if measure is None or measure(option) is None:
        return None
    scored = [(abs(measure(s) - measure(option)), -measure(s), s) for s in supported if measure(s) is not None]
    return min(scored)[2] if scored else None
