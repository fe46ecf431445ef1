"""Sensor drivers: identification, bring-up, start/stop and settings (biases, ROI, ERC, trigger).

One class per Treuzell main device (``docs/evk-usb.md`` sections 2.7, 3): :class:`Imx636`
(EVK4 and EVK3-HD with IMX636), :class:`Gen31` (EVK3 VGA) and :class:`Gen41` (older
EVK3-HD, best effort). Register sequences are data in ``seq_*`` modules; this module only
orders them and computes the few values that depend on user input.
"""

from __future__ import annotations

import math

import numpy as np

from . import seq_gen31, seq_gen41, seq_imx636
from .errors import BiasRangeError, EvkError
from .treuzell import TzLink

IMX636_BIAS_OFFSET_RANGES = {
    # HAL recommended offset ranges (enforced by default), offsets from the factory trim.
    "bias_fo": (-35, 55),
    "bias_hpf": (0, 120),
    "bias_diff_on": (-85, 140),
    "bias_diff": (-25, 23),
    "bias_diff_off": (-35, 190),
    "bias_refr": (-20, 235),
}
BIAS_WORD = 0x11A10000  # buf_stg 1, mux_en, buf_en, idac_en, single; idac_ctl in [7:0]


def _normalise_bias_names(named: dict, known) -> dict:
    out = {}
    for key, value in named.items():
        name = key if key.startswith("bias_") else f"bias_{key}"
        if name not in known:
            raise BiasRangeError(f"unknown bias {key!r}; known: {', '.join(sorted(known))}")
        if int(value) != value:
            raise BiasRangeError(f"bias {name} must be an integer, got {value!r}")
        out[name] = int(value)
    return out


def _bitmap_words(first: int, count: int, n_lines: int, n_words: int) -> list[int]:
    """u32 words with bit ``k`` set for every line ``first <= k < first + count`` (1 = keep)."""
    bits = np.zeros(n_words * 32, dtype=np.uint8)
    bits[first:first + count] = 1
    bits[n_lines:] = 0
    packed = np.packbits(bits.reshape(n_words, 32)[:, ::-1], axis=1)  # MSB first per word
    return [int.from_bytes(bytes(row), "big") for row in packed]


def _check_window(x, y, width, height, sensor_w, sensor_h, name) -> None:
    if width <= 0 or height <= 0 or x < 0 or y < 0 or x + width > sensor_w or y + height > sensor_h:
        raise ValueError(
            f"ROI x={x}, y={y}, width={width}, height={height} does not fit the {name}'s "
            f"{sensor_w}x{sensor_h} pixels"
        )


class Imx636:
    """Sony IMX636 (Prophesee Gen4.2) behind the EVK4 / EVK3-HD CX3 firmware."""

    name = "IMX636"
    compatible = ("psee,ccam5_imx636", "psee,ccam5_gen42")
    width, height = 1280, 720
    seq = seq_imx636

    def __init__(self, link: TzLink, device: int):
        self.link = link
        self.device = device
        self.factory_biases: dict[str, int] = {}
        self.biases: dict[str, int] = {}
        self.erc_count = seq_imx636.ERC_DEFAULT_COUNT
        self.anti_flicker_hz: tuple[int, int] | None = None
        self.trail_filter: tuple[str, int] | None = None
        self.sync_mode = "standalone"

    @classmethod
    def probe(cls, link: TzLink, device: int) -> bool:
        """HAL check: chip id 0xA0401806 and variant bits 0xF128[1:0] == 0 (not IMX646)."""
        if link.read_reg(device, seq_imx636.CHIP_ID_ADDRESS) != seq_imx636.CHIP_ID:
            return False
        return link.read_reg(device, seq_imx636.VARIANT_ADDRESS) & 0x3 == 0

    def run(self, ops) -> list[int]:
        return self.link.run(self.device, ops)

    # ---- lifecycle ----------------------------------------------------------------------
    def bring_up(self) -> None:
        """Open-time sequence: stop, destroy, init, then the HAL's post-init accesses."""
        s = self.seq
        self.run(s.STOP)
        self.run(s.DESTROY)
        self.run(s.INIT)
        self.run(s.POST_INIT)
        self.run(s.ERC_INIT)
        self._read_biases()
        self.run(s.ROI_RESET)
        self.run(s.TRIGGER_IN_DISABLE)
        self.run(s.STANDALONE)

    def _read_biases(self) -> None:
        names = list(seq_imx636.BIAS_ADDRESSES)
        values = self.run([("R", seq_imx636.BIAS_ADDRESSES[n]) for n in names])
        self.factory_biases = {n: v & 0xFF for n, v in zip(names, values)}
        self.biases = {n: 0 for n in names}

    def start(self) -> None:
        self.run(self.seq.START)

    def stop(self) -> None:
        self.run(self.seq.STOP)

    def destroy(self) -> None:
        self.run(self.seq.DESTROY)

    def event_format(self) -> str:
        """Current output format from ``edf/pipeline_control`` bit 1 (as the HAL)."""
        value = self.link.read_reg(self.device, seq_imx636.EDF_PIPELINE_CONTROL)
        return "EVT21" if value & 0x2 else "EVT3"

    # ---- biases -------------------------------------------------------------------------
    def set_biases(self, **named: int) -> None:
        """Set biases as offsets from the factory trim (HAL semantics), e.g. ``bias_fo=10``.

        Every value is checked against the HAL's recommended offset range before anything is
        written; the register gets ``0x11A10000 | clamp(default + offset, 0, 255)``.
        [uncertain] The init sequence writes bias_diff with vdac_ctl = 0x50 and the Linux driver
        sets scr_set for fo/hpf/refr; we follow the HAL's set path (vdac_ctl = 0, no scr_set),
        whose analog effect is what Metavision users get.
        """
        values = _normalise_bias_names(named, IMX636_BIAS_OFFSET_RANGES)
        for name, offset in values.items():
            lo, hi = IMX636_BIAS_OFFSET_RANGES[name]
            if not lo <= offset <= hi:
                raise BiasRangeError(
                    f"{name} offset {offset} is outside the {self.name}'s recommended range {lo}..{hi}"
                )
        for name, offset in values.items():
            current = min(max(self.factory_biases[name] + offset, 0), 255)
            self.link.write_reg(self.device, seq_imx636.BIAS_ADDRESSES[name], BIAS_WORD | current)
            self.biases[name] = current - self.factory_biases[name]

    def get_biases(self) -> dict[str, int]:
        """Current bias offsets from the factory trim."""
        return dict(self.biases)

    # ---- ROI ----------------------------------------------------------------------------
    def set_roi(self, x=None, y=None, width=None, height=None) -> None:
        """Keep only the window ``[x, x+width) x [y, y+height)`` (line bitmaps, ROI mode);
        no arguments restores the full frame.

        Uses the line bitmaps (section 3.7 A; 1 = line disabled on this sensor) rather than
        the hardware window, whose end coordinate is ambiguous between sources (3.7 B). Like
        the HAL's ``enable``, this sets ``px_td_rstn`` (releases the pixels).
        """
        s = self.seq
        if x is None and y is None and width is None and height is None:
            self.run(s.ROI_RESET)
            self._roi_enable(False)
            return
        _check_window(x, y, width, height, self.width, self.height, self.name)
        cols = _bitmap_words(x, width, self.width, len(s.ROI_X_ADDRESSES))
        rows = _bitmap_words(y, height, self.height, len(s.ROI_Y_ADDRESSES))
        ops = [("W", a, ~v & 0xFFFFFFFF) for a, v in zip(s.ROI_X_ADDRESSES, cols)]
        ops += [("W", a, ~v & 0xFFFFFFFF) for a, v in zip(s.ROI_Y_ADDRESSES, rows)]
        last = ops[-1]
        ops[-1] = ("W", last[1], last[2] | 0xFFFF0000)  # HAL forces the unused rows off
        self.run(ops)
        self._roi_enable(True)

    def set_crop(self, x=None, y=None, width=None, height=None) -> None:
        """Drop, in the digital readout, the events outside ``[x, x+width) x [y, y+height)``
        (coordinates stay the sensor's); no arguments switches the crop off. The HAL's register
        traffic (``Gen41DigitalCrop``: ``set_window_region`` without resetting the origin, then
        ``enable``): each field a read-modify-write.
        """
        s = seq_imx636
        if x is None and y is None and width is None and height is None:
            self.run((("RMW", s.DIG_CTRL, 0, 0x7),))
            return
        _check_window(x, y, width, height, self.width, self.height, self.name)
        x1, y1 = x + width - 1, y + height - 1  # the region's last pixel
        self.run((
            ("RMW", s.DIG_START_POS, x, 0x7FF), ("RMW", s.DIG_START_POS, y << 16, 0x3FF << 16),
            ("RMW", s.DIG_END_POS, x1, 0x7FF), ("RMW", s.DIG_END_POS, y1 << 16, 0x3FF << 16),
            ("RMW", s.DIG_CTRL, 0, 1 << 4),  # keep the sensor's coordinates
            ("RMW", s.DIG_CTRL, 5, 0x7),
        ))

    def _roi_enable(self, state: bool) -> None:
        bits = (1 << 1) | (1 << 5) | (1 << 6) | (1 << 10)
        value = (int(state) << 1) | (1 << 5) | (1 << 6) | (1 << 10)
        self.run((("RMW", 0x0004, value, bits), ("RMW", 0x0034, 0, 0x3)))

    # ---- anti-flicker --------------------------------------------------------------------
    def set_anti_flicker(self, band_hz: tuple[int, int] | None) -> None:
        """Drop the events of lights flickering within ``band_hz = (low, high)`` (Hz, 50..520)
        with the sensor's anti-flicker block (band-stop, 50 % duty cycle, hysteresis 6/4: the
        HAL's defaults); ``None`` switches it off.

        The HAL's register traffic (``AntiFlickerFilter::enable``): pipeline off, the
        initialisation flag polled up to three times, then invalidation, band, mode and
        hysteresis, pipeline on. A spinning textured ball also fires periodically (at its spin
        rate times the texture's repeats): keep the band narrow around the lights' frequency
        (twice the mains frequency).

        Raises
        ------
        ValueError
            A band outside 50..520 Hz or with low > high.
        EvkError
            The block does not report its initialisation done.
        """
        s = seq_imx636
        self.run((("W", s.AFK_PIPELINE_CONTROL, 0b101),))
        self.anti_flicker_hz = None
        if band_hz is None:
            return
        low, high = (int(v) for v in band_hz)
        if not s.AFK_BAND_HZ[0] <= low <= high <= s.AFK_BAND_HZ[1]:
            raise ValueError(f"anti-flicker band {low}..{high} Hz is outside {s.AFK_BAND_HZ[0]}..{s.AFK_BAND_HZ[1]} Hz "
                             "(or low > high)")
        if not any(self.link.read_reg(self.device, s.AFK_INITIALIZATION) & (1 << 2) for _ in range(3)):
            raise EvkError(f"{self.name} anti-flicker did not report its initialisation done (register 0xC0C4)")
        min_period, max_period = int(1e6 / high) >> 7, int(1e6 / low) >> 7
        d = s.AFK_DEFAULTS
        self.run((
            ("RMW", s.AFK_INVALIDATION, 1630, 0xFFF),
            ("RMW", s.AFK_FILTER_PERIOD, min_period | max_period << 8 | d["inverted_duty_cycle"] << 16, 0xFFFFF),
            ("RMW", s.AFK_PARAM, 0, 1 << 6),
            ("RMW", s.AFK_PARAM, d["counter_high"] << 3, 0x7 << 3),
            ("RMW", s.AFK_PARAM, d["counter_low"], 0x7),
            ("W", s.AFK_PIPELINE_CONTROL, 0b001),
        ))
        self.anti_flicker_hz = (low, high)

    # ---- temperature ----------------------------------------------------------------------
    def temperature_c(self) -> float:
        """Die temperature, °C, from the sensor's ADC, with the HAL's register traffic
        (``TzImx636::get_temperature``): ADC clock on, temperature input, start; the done flag and
        value polled up to five times (each a read of ``adc_status``); ADC clock off.

        Raises
        ------
        EvkError
            The ADC did not report a conversion done.
        """
        s = seq_imx636
        self.run((("RMW", s.ADC_CONTROL, 1 << 1, 1 << 1), ("RMW", s.ADC_MISC_CTRL, 1 << 12, 1 << 12),
                  ("RMW", s.ADC_CONTROL, 1 << 2, 1 << 2)))
        for _ in range(5):
            done, value = self.run((("R", s.ADC_STATUS), ("R", s.ADC_STATUS)))
            if done >> 11 & 1:
                break
        else:
            raise EvkError(f"{self.name} temperature ADC did not report a conversion (register 0x{s.ADC_STATUS:04X})")
        self.run((("RMW", s.ADC_CONTROL, 0, 1 << 1),))
        return s.TEMPERATURE_C_PER_STEP * (value & 0x3FF) + s.TEMPERATURE_OFFSET_C

    def illuminance_lux(self) -> float:
        """Light level on the sensor, lux, from its LIFO on-time counter, with the HAL's register
        traffic (``TzImx636::get_illumination``: ``lifo_status`` read up to ten times until valid).

        Raises
        ------
        EvkError
            The counter never became valid, or reads 0 (no level to give).
        """
        s = seq_imx636
        for _ in range(10):
            (status,) = self.run((("R", s.LIFO_STATUS),))
            if status >> 29 & 1:
                break
        else:
            raise EvkError(f"{self.name} light counter did not report a value (register 0x{s.LIFO_STATUS:04X})")
        counter = status & ((1 << 27) - 1)
        if counter == 0:
            raise EvkError(f"{self.name} light counter reads 0: no light level")
        return s.illuminance_lux(counter)

    # ---- ERC ----------------------------------------------------------------------------
    def set_erc(self, max_event_rate_ev_s: float | None) -> None:
        """Cap the sensor's output at ``max_event_rate_ev_s`` (events/s); ``None`` disables."""
        if max_event_rate_ev_s is None:
            self.run(seq_imx636.ERC_DISABLE)
            return
        period_us = self.link.read_reg(self.device, seq_imx636.ERC_REFERENCE_PERIOD) & 0x3FF
        count = int(max_event_rate_ev_s * period_us / 1_000_000)
        if max_event_rate_ev_s < 0 or count > seq_imx636.ERC_MAX_COUNT:
            raise ValueError(
                f"max_event_rate_ev_s={max_event_rate_ev_s} is outside 0..{seq_imx636.ERC_MAX_COUNT * 1e6 / max(period_us, 1):.0f} ev/s"
            )
        self.link.write_reg(self.device, seq_imx636.ERC_TARGET, count)
        self.run(seq_imx636.ERC_ENABLE)
        self.link.write_reg(self.device, seq_imx636.ERC_TARGET, count)
        self.erc_count = count

    def erc_status(self) -> tuple[bool, float]:
        """(enabled, cap in events/s) read back from the sensor as the HAL does
        (``Gen41Erc::is_enabled``, ``get_cd_event_rate``): running and dropping, and the target
        count per reference period. The register map has no drop counter."""
        s = seq_imx636
        control, dropping, period_us, count = self.run((("R", s.ERC_CONTROL), ("R", s.ERC_T_DROPPING),
                                                        ("R", s.ERC_REFERENCE_PERIOD), ("R", s.ERC_TARGET)))
        enabled = control & 0x3 == 1 and bool(dropping & 1)
        return enabled, count * 1_000_000 / period_us if period_us else float("nan")

    # ---- event format -------------------------------------------------------------------
    def set_event_format(self, fmt: str) -> None:
        """Select the output format, ``"EVT3"`` or ``"EVT21"`` (EVT 2.1, legacy word order; 8
        bytes per event word instead of 2): the HAL's two RMWs, only while not streaming."""
        if fmt not in seq_imx636.FORMATS:
            raise ValueError(f"{self.name} streams EVT3 or EVT21, not {fmt!r}")
        self.run(seq_imx636.FORMATS[fmt])

    # ---- event trail filter ---------------------------------------------------------------
    def set_trail_filter(self, kind: str | None, threshold_us: int = 10_000) -> None:
        """Filter bursts and noise in the sensor (OpenEB ``EventTrailFilter``): ``kind`` one of
        ``seq_imx636.STC_KINDS`` (``trail``, ``stc_cut``, ``stc_keep``), ``threshold_us`` the
        longest gap inside a burst, 1,000..100,000 µs, rounded to whole ms as the HAL does;
        ``None`` bypasses the block.

        The HAL's register traffic: bypass, clear the init flag and start the SRAM init, the
        kind's parameters, the time base for the threshold (its table), the init flag polled
        up to three times, then on.

        Raises
        ------
        ValueError
            An unknown kind or a threshold out of range (nothing written).
        EvkError
            The block does not report its initialisation done (it is left bypassed).
        """
        s = seq_imx636
        if kind is not None and kind not in s.STC_KINDS:
            raise ValueError(f"trail filter kind must be one of {', '.join(s.STC_KINDS)}, got {kind!r}")
        ms = math.floor(threshold_us / 1000.0 + 0.5)  # C's roundf: halves away from zero, as the HAL
        low, high = s.STC_THRESHOLD_US
        if kind is not None and not (low <= threshold_us <= high):
            raise ValueError(f"trail filter threshold {threshold_us} µs is outside {low}..{high} µs")
        self.run((("W", s.STC_PIPELINE_CONTROL, 0b101),))
        self.trail_filter = None
        if kind is None:
            return
        prescaler, multiplier, timeout = s.STC_TIMING[ms - 1]
        field = (ms * 1000) << 1
        if kind == "trail":
            params = (("RMW", s.STC_PARAM, 0, 1),
                      ("RMW", s.TRAIL_PARAM, 1 | field, 0xFFFFF))
        else:
            keep = int(kind == "stc_keep") << 24
            params = (("RMW", s.STC_PARAM, 1 | field | keep, 0xFFFFF | 1 << 24),
                      ("RMW", s.TRAIL_PARAM, 0, 1))
        self.run((("RMW", s.STC_INITIALIZATION, 1 << 2, 1 << 2), ("RMW", s.STC_INITIALIZATION, 1, 1), *params,
                  ("RMW", s.STC_TIMESTAMPING, prescaler | multiplier << 5 | 1 << 16, 0x1F | 0xF << 5 | 1 << 16),
                  ("RMW", s.STC_INVALIDATION, timeout << 12, 0xFFF << 12)))
        if not any(self.link.read_reg(self.device, s.STC_INITIALIZATION) & (1 << 2) for _ in range(3)):
            raise EvkError(f"{self.name} trail filter did not report its initialisation done (register 0xD0C4)")
        self.run((("W", s.STC_PIPELINE_CONTROL, 0b001),))
        self.trail_filter = (kind, ms * 1000)

    # ---- synchronisation ------------------------------------------------------------------
    def set_sync_mode(self, mode: str) -> None:
        """Time base of several cameras: ``"standalone"`` (own clock), ``"master"`` (drives the
        SYNC pad) or ``"slave"`` (follows it); the HAL's ``time_base_config``. Set it before
        starting; start the slave before the master."""
        if mode not in seq_imx636.SYNC_MODES:
            raise ValueError(f"sync mode must be one of {', '.join(seq_imx636.SYNC_MODES)}, got {mode!r}")
        self.run(seq_imx636.SYNC_MODES[mode])
        self.sync_mode = mode

    # ---- trigger in ---------------------------------------------------------------------
    def enable_trigger_in(self, enabled: bool = True, channel: int = 0) -> None:
        """Enable or disable external trigger input channel 0 (``Main``; the only one)."""
        if channel != 0:
            raise ValueError(f"{self.name} has trigger-in channel 0 only, got {channel}")
        self.run(self.seq.TRIGGER_IN_ENABLE if enabled else self.seq.TRIGGER_IN_DISABLE)


class Gen41(Imx636):
    """Prophesee Gen4.1 on older EVK3-HD boards (best effort, section 3.14)."""

    name = "Gen4.1"
    compatible = ("psee,ccam5_gen41",)
    seq = seq_gen41
    temperature_c = None  # the HAL reads no temperature from a Gen4.1 behind the CX3 (EVK3 HD)
    illuminance_lux = None  # nor a light level
    set_trail_filter = None  # its STC block has other fields and thresholds: not driven here
    set_sync_mode = None  # nor its time-base synchronisation
    set_event_format = None  # nor its format selection (EVT3 only)

    @classmethod
    def probe(cls, link: TzLink, device: int) -> bool:
        return link.read_reg(device, 0x0014) in seq_gen41.CHIP_IDS

    def bring_up(self) -> None:
        """stop, destroy, init; mirror + LIFO, ERC initialise and enable, ROI reset, trigger
        disabled, standalone (no temperature ADC set-up on Gen4.1)."""
        s, i = seq_gen41, seq_imx636
        self.run(s.STOP)
        self.run(s.DESTROY)
        self.run(s.INIT)
        self.run(i.POST_INIT_MIRROR + i.POST_INIT_LIFO)
        self.run(i.ERC_INIT)
        self.run(i.ERC_ENABLE)
        self.link.write_reg(self.device, i.ERC_TARGET, self.erc_count)
        names = list(s.BIAS_REGISTERS)
        values = self.run([("R", s.BIAS_REGISTERS[n][0]) for n in names])
        self.biases = {n: v & 0xFF for n, v in zip(names, values)}
        self.run(i.ROI_RESET)
        self.run(i.TRIGGER_IN_DISABLE)
        self.run(i.STANDALONE)

    def set_biases(self, **named: int) -> None:
        """Absolute 0-255 biases, within the HAL's recommended ranges, with
        ``diff_on >= diff + 15`` and ``diff_off <= diff - 15``."""
        values = _normalise_bias_names(named, seq_gen41.BIAS_REGISTERS)
        for name, value in values.items():
            _, lo, hi = seq_gen41.BIAS_REGISTERS[name]
            if not lo <= value <= hi:
                raise BiasRangeError(f"{name} = {value} is outside the Gen4.1's recommended range {lo}..{hi}")
        merged = {**self.biases, **values}
        if merged["bias_diff_on"] < merged["bias_diff"] + 15:
            raise BiasRangeError("Gen4.1 needs bias_diff_on >= bias_diff + 15")
        if merged["bias_diff_off"] > merged["bias_diff"] - 15:
            raise BiasRangeError("Gen4.1 needs bias_diff_off <= bias_diff - 15")
        for name, value in values.items():
            self.link.write_reg(self.device, seq_gen41.BIAS_REGISTERS[name][0], BIAS_WORD | value)
            self.biases[name] = value


class Gen31:
    """Prophesee Gen3.1 VGA sensor behind the EVK3 FPGA (``psee,ccam5_fpga``)."""

    name = "Gen3.1"
    compatible = ("psee,ccam5_fpga",)
    width, height = 640, 480
    seq = seq_gen31

    def __init__(self, link: TzLink, device: int):
        self.link = link
        self.device = device
        self.nfl_kev_s: float | None = None

    @classmethod
    def probe(cls, link: TzLink, device: int) -> bool:
        value = link.read_reg(device, seq_gen31.SYSTEM_ID_ADDRESS) & 0xFF
        if value != seq_gen31.SYSTEM_ID:
            raise EvkError(f"wrong FPGA system ID 0x{value:02X} (expected 0x28 for an EVK3 Gen3.1)")
        return True

    def run(self, ops) -> list[int]:
        return self.link.run(self.device, ops)

    def bring_up(self) -> None:
        s = self.seq
        self.run(s.STOP)
        self.run(s.DESTROY)
        self.run(s.INIT)
        self.run(s.POST_INIT)

    def start(self) -> None:
        self.run(self.seq.START)
        if self.nfl_kev_s is not None:
            # The start sequence disables the noise filter (0x248 = 0xC8); re-enable it.
            self._nfl_on()

    def stop(self) -> None:
        self.run(self.seq.STOP)

    def destroy(self) -> None:
        self.run(self.seq.DESTROY)

    def event_format(self) -> str:
        return "EVT3"

    def set_biases(self, **named: int) -> None:
        """Range-checks Gen3.1 biases (absolute mV) but cannot write them.

        Encoding a Gen3.1 bias needs openeb's four calibration tables, which this project
        does not ship; the sensor keeps the init sequence's standard biases.
        """
        values = _normalise_bias_names(named, seq_gen31.BIAS_REGISTERS)
        for name, value in values.items():
            _, lo, hi = seq_gen31.BIAS_REGISTERS[name]
            if not lo <= value <= hi:
                raise BiasRangeError(f"{name} = {value} mV is outside the Gen3.1's recommended range {lo}..{hi} mV")
        raise EvkError(
            "setting Gen3.1 biases needs openeb's bias calibration tables (not shipped); "
            "the sensor keeps its standard biases"
        )

    def get_biases(self) -> dict[str, int]:
        return {}

    def set_roi(self, x=None, y=None, width=None, height=None) -> None:
        """Keep the window ``[x, x+width) x [y, y+height)``; no arguments: full frame."""
        s = self.seq
        if x is None and y is None and width is None and height is None:
            cols = [0xFFFFFFFF] * len(s.ROI_X_ADDRESSES)
            rows = [0xFFFFFFFF] * len(s.ROI_Y_ADDRESSES)
        else:
            _check_window(x, y, width, height, self.width, self.height, self.name)
            cols = _bitmap_words(x, width, self.width, len(s.ROI_X_ADDRESSES))
            rows = _bitmap_words(y, height, self.height, len(s.ROI_Y_ADDRESSES))
        ops = [("W", a, v) for a, v in zip(s.ROI_X_ADDRESSES, cols)]
        ops += [("W", a, v) for a, v in zip(s.ROI_Y_ADDRESSES, rows)]
        self.run(tuple(ops) + s.ROI_APPLY)

    def set_erc(self, max_event_rate_ev_s: float | None) -> None:
        """Gen3.1 has no event rate controller: a cap is refused (``None`` is accepted, nothing to do).

        Its only rate-based block, the NFL, is an activity filter (OpenEB's
        ``I_EventRateActivityFilterModule`` with a lower bound): it drops events while the rate is
        *below* its threshold, so using it as a cap would blank quiet scenes. It is
        :meth:`set_activity_filter`.
        """
        if max_event_rate_ev_s is not None:
            raise EvkError("the EVK3 Gen3.1 has no event rate controller, so no event-rate cap (--erc); "
                           "its NFL is an activity filter that drops events while the rate is below a threshold")

    def set_activity_filter(self, min_event_rate_ev_s: float | None) -> None:
        """Drop events while the sensor's rate is below ``min_event_rate_ev_s`` (the NFL,
        10..10000 kev/s over a 1023 µs window): removes background noise in a still scene, and
        everything in a quiet one. ``None`` disables it."""
        if min_event_rate_ev_s is None:
            self.nfl_kev_s = None
            self.run((("RMW", seq_gen31.NFL_CTRL, 0, 1),))
            return
        kev_s = min_event_rate_ev_s / 1000
        if not 10 <= kev_s <= 10000:
            raise ValueError(
                f"min_event_rate_ev_s={min_event_rate_ev_s} is outside the Gen3.1 activity filter's 1e4..1e7 ev/s"
            )
        self.nfl_kev_s = kev_s
        self._nfl_on()

    def _nfl_on(self) -> None:
        window_us = 1023
        thresh = round(self.nfl_kev_s / 1000 * window_us)
        self.run((
            ("RMW", seq_gen31.NFL_THRESH, thresh | (window_us << 14), 0x00FFFFFF),
            ("RMW", seq_gen31.NFL_CTRL, 1, 1),
        ))

    def enable_trigger_in(self, enabled: bool = True, channel: int = 0) -> None:
        """Enable or disable external trigger input channel 0 (``Main``)."""
        if channel != 0:
            raise ValueError(f"{self.name} trigger-in: only channel 0 (Main) is supported, got {channel}")
        self.run(self.seq.TRIGGER_IN_ENABLE if enabled else self.seq.TRIGGER_IN_DISABLE)


DRIVERS = (Imx636, Gen31, Gen41)
"""Sensor drivers in the order their compatible strings are tried."""

IMX646_COMPATIBLE = "psee,ccam5_imx646"


def driver_for(compatible: str):
    """Driver class for a Treuzell compatible string, or ``None``."""
    for cls in DRIVERS:
        if compatible in cls.compatible:
            return cls
    return None
