"""IMX636 (EVK4, EVK3-HD with IMX636) register sequences, as data.

Transcribed from ``docs/evk-usb.md`` Appendix A (``issd_evk3_imx636_*``) and Appendix B (the
HAL's ordered accesses after the init sequence). All accesses go to the main Treuzell
device. Ops (see :mod:`capture.evk.treuzell`):

- ``("W", address, value)``: write the whole 32-bit register;
- ``("RMW", address, value, mask)``: read, then write ``(old & ~mask) | (value & mask)``;
- ``("R", address)``: read, result unused (as the HAL);
- ``("D", microseconds)``: wait. We sleep the *nominal* value (the HAL truncates to whole
  milliseconds, so ours is never shorter).

Run order: open = STOP, DESTROY, INIT, then POST_INIT_*; start = START; stop = STOP;
close = DESTROY.
"""

import math

INIT = (
    ("W", 0x0000001C, 0x00000001),  # 1 unnamed (not in public maps)
    ("D", 1000000),  # 2
    ("W", 0x00400004, 0x00000001),  # 3 MBX region +4 [K names base 0x400000 'MBX']; pulse 1→0 (reset-like, name unverified)
    ("D", 500000),  # 4
    ("W", 0x00400004, 0x00000000),  # 5 MBX region +4 [K names base 0x400000 'MBX']; pulse 1→0 (reset-like, name unverified)
    ("D", 1000000),  # 6
    ("W", 0x0000B000, 0x00000158),  # 7 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("D", 300),  # 8
    ("W", 0x0000B044, 0x00000000),  # 9 MIPI_STREAM [K]
    ("W", 0x0000B004, 0x0000000A),  # 10 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("W", 0x0000B040, 0x00000000),  # 11 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B0C8, 0x00000000),  # 12 MIPI DPHY_POWER [K] (b0 BIASEN, b1 LPREGEN)
    ("W", 0x0000B040, 0x00000000),  # 13 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B040, 0x00000000),  # 14 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x00000000, 0x4F006442),  # 15 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x0F006442),  # 16 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x000000B8, 0x00000400),  # 17 DV_CTRL [K] (bit0 PC_CLKDIVEN, bit3 PC_SYSCLKEN)
    ("W", 0x000000B8, 0x00000400),  # 18 DV_CTRL [K] (bit0 PC_CLKDIVEN, bit3 PC_SYSCLKEN)
    ("W", 0x0000B07C, 0x00000000),  # 19 MIPI PL_RG_7 [K] (b0 XCLR_LV, b1 XSTB_OP, b2 LOCKDET read-only)
    ("W", 0x0000B074, 0x00000002),  # 20 MIPI PL_RG_5 [K] (PLL input divider)
    ("W", 0x0000B078, 0x000000A0),  # 21 MIPI PL_RG_6 [K] (PLL feedback divider)
    ("W", 0x000000C0, 0x00000110),  # 22 GLOBAL_CTRL2 [K] (bits7:0 DVTOP divider, bits10:8 SYS_CLK_DIVIDER)
    ("W", 0x000000C0, 0x00000210),  # 23 GLOBAL_CTRL2 [K] (bits7:0 DVTOP divider, bits10:8 SYS_CLK_DIVIDER)
    ("W", 0x0000B120, 0x00000001),  # 24 MIPI BYTECLK_CTRL [K]
    ("W", 0x0000E120, 0x00000000),  # 25 SLVS LINKCLK_CTRL [K]
    ("W", 0x0000B068, 0x00000004),  # 26 MIPI PL_RG_2 [K] (bit2 ENDET_OP)
    ("W", 0x0000B07C, 0x00000001),  # 27 MIPI PL_RG_7 [K] (b0 XCLR_LV, b1 XSTB_OP, b2 LOCKDET read-only)
    ("D", 10),  # 28
    ("W", 0x0000B07C, 0x00000003),  # 29 MIPI PL_RG_7 [K] (b0 XCLR_LV, b1 XSTB_OP, b2 LOCKDET read-only)
    ("D", 1000),  # 30
    ("W", 0x000000B8, 0x00000401),  # 31 DV_CTRL [K] (bit0 PC_CLKDIVEN, bit3 PC_SYSCLKEN)
    ("W", 0x000000B8, 0x00000409),  # 32 DV_CTRL [K] (bit0 PC_CLKDIVEN, bit3 PC_SYSCLKEN)
    ("W", 0x00000000, 0x4F006442),  # 33 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x4F00644A),  # 34 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x0000B080, 0x00000077),  # 35 D-PHY TCLKPOST [K]
    ("W", 0x0000B084, 0x0000000F),  # 36 D-PHY TCLKPRE [K]
    ("W", 0x0000B088, 0x00000037),  # 37 D-PHY TCLKPREPARE [K]
    ("W", 0x0000B08C, 0x00000037),  # 38 D-PHY TCLKTRAIL [K]
    ("W", 0x0000B090, 0x000000DF),  # 39 D-PHY TCLKZERO [K]
    ("W", 0x0000B094, 0x00000057),  # 40 D-PHY THSEXIT [K]
    ("W", 0x0000B098, 0x00000037),  # 41 D-PHY THSPREPARE [K]
    ("W", 0x0000B09C, 0x00000067),  # 42 D-PHY THSZERO [K]
    ("W", 0x0000B0A0, 0x00000037),  # 43 D-PHY THSTRAIL [K]
    ("W", 0x0000B0A4, 0x0000002F),  # 44 D-PHY TLPX [K]
    ("W", 0x0000B0AC, 0x00000028),  # 45 D-PHY TXCLKESC_FREQ [K]
    ("W", 0x0000B0CC, 0x00000001),  # 46 MIPI DPHY_PLL_DIV [K]
    ("W", 0x0000B000, 0x000002F8),  # 47 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("W", 0x0000B004, 0x0000008A),  # 48 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("W", 0x0000B01C, 0x00000030),  # 49 unnamed (MIPI block)
    ("W", 0x0000B020, 0x00002000),  # 50 mipi_csi/mipi_packet_size [R]
    ("W", 0x0000B02C, 0x000000FF),  # 51 mipi_csi/mipi_line_blanking [R]
    ("W", 0x0000B030, 0x00003E80),  # 52 mipi_csi/mipi_frame_blanking [R]
    ("W", 0x0000B028, 0x00000FA0),  # 53 mipi_csi/mipi_frame_period [R]
    ("W", 0x0000A000, 0x000B0501),  # 54 unnamed (analog power block)
    ("D", 200),  # 55
    ("W", 0x0000A008, 0x00002405),  # 56 unnamed (analog power block)
    ("D", 200),  # 57
    ("W", 0x0000A004, 0x000B0501),  # 58 unnamed (analog power block)
    ("D", 200),  # 59
    ("W", 0x0000A020, 0x00000150),  # 60 unnamed (analog power block)
    ("D", 200),  # 61
    ("W", 0x0000B040, 0x00000007),  # 62 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B064, 0x00000006),  # 63 MIPI PL_RG_1 [K] (bit1 CKOUTEN)
    ("W", 0x0000B040, 0x0000000F),  # 64 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("D", 100),  # 65
    ("W", 0x0000B004, 0x0000008A),  # 66 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("D", 200),  # 67
    ("W", 0x0000B0C8, 0x00000003),  # 68 MIPI DPHY_POWER [K] (b0 BIASEN, b1 LPREGEN)
    ("D", 200),  # 69
    ("W", 0x0000B044, 0x00000001),  # 70 MIPI_STREAM [K]
    ("W", 0x0000B000, 0x000002F9),  # 71 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("W", 0x00007008, 0x00000001),  # 72 unnamed (EDF block)
    ("W", 0x00007000, 0x00070001),  # 73 edf/pipeline_control [R] (bit1 format: 0=EVT3, 1=EVT2.1)
    ("W", 0x00008000, 0x0001E085),  # 74 eoi/pipeline control [R][K] (bits7:6 byte order)
    ("W", 0x00009008, 0x00000644),  # 75 ro/time_base_ctrl [R]
    ("W", 0x00000004, 0xF0005042),  # 76 roi_ctrl [R]
    ("W", 0x00000018, 0x00000200),  # 77 spare0 / SPARE_CTRL0 [R][K]
    ("W", 0x00001014, 0x11A1504D),  # 78 bias/bias_diff [R]
    ("W", 0x00009004, 0x00000000),  # 79 ro/ro_fsm_ctrl [R] (readout_wait)
    ("D", 1000),  # 80
    ("W", 0x00009000, 0x00000200),  # 81 ro/readout_ctrl [R][K] (0x200 = digital pipe only)
)

START = (
    ("W", 0x0000B000, 0x000002F9),  # 1 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("W", 0x00009028, 0x00000000),  # 2 ro/ro_ctrl (RO_LP_CTRL) [R][K] (bit1 output_disable)
    ("RMW", 0x00009008, 0x00000645, 0x00000001),  # 3 ro/time_base_ctrl [R]
    # Analog START
    ("W", 0x0000002C, 0x0022C724),  # 4 unnamed; 'analog start/stop' (bit10) [I]
    ("RMW", 0x00000004, 0xF0005442, 0x00000400),  # 5 roi_ctrl [R]
)

STOP = (
    # Analog STOP
    ("RMW", 0x00000004, 0xF0005042, 0x00000400),  # 1 roi_ctrl [R]
    ("W", 0x0000002C, 0x0022C324),  # 2 unnamed; 'analog start/stop' (bit10) [I]
    # Digital STOP
    ("W", 0x00009028, 0x00000002),  # 3 ro/ro_ctrl (RO_LP_CTRL) [R][K] (bit1 output_disable)
    ("D", 1000),  # 4
    ("RMW", 0x00009008, 0x00000644, 0x00000001),  # 5 ro/time_base_ctrl [R]
    ("W", 0x0000B000, 0x000002F8),  # 6 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("D", 300),  # 7
)

DESTROY = (
    # Analog DESTROY
    ("W", 0x00000070, 0x00400008),  # 1 unnamed (analog power)
    ("W", 0x0000006C, 0x0EE47114),  # 2 unnamed (analog power)
    ("D", 500),  # 3
    ("W", 0x0000A00C, 0x00020400),  # 4 unnamed (analog power block)
    ("D", 500),  # 5
    ("W", 0x0000A010, 0x00008068),  # 6 unnamed (analog power block)
    ("D", 200),  # 7
    ("W", 0x00001104, 0x00000000),  # 8 unnamed (bias generator)
    ("D", 200),  # 9
    ("W", 0x0000A020, 0x00000050),  # 10 unnamed (analog power block)
    ("D", 200),  # 11
    ("W", 0x0000A004, 0x000B0500),  # 12 unnamed (analog power block)
    ("D", 200),  # 13
    ("W", 0x0000A008, 0x00002404),  # 14 unnamed (analog power block)
    ("D", 200),  # 15
    ("W", 0x0000A000, 0x000B0500),  # 16 unnamed (analog power block)
    # Digital DESTROY
    ("W", 0x0000B044, 0x00000000),  # 17 MIPI_STREAM [K]
    ("W", 0x0000B004, 0x0000000A),  # 18 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("W", 0x0000B040, 0x0000000E),  # 19 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B0C8, 0x00000000),  # 20 MIPI DPHY_POWER [K] (b0 BIASEN, b1 LPREGEN)
    ("W", 0x0000B040, 0x00000006),  # 21 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B040, 0x00000004),  # 22 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x00000000, 0x4F006442),  # 23 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x0F006442),  # 24 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x000000B8, 0x00000401),  # 25 DV_CTRL [K] (bit0 PC_CLKDIVEN, bit3 PC_SYSCLKEN)
    ("W", 0x000000B8, 0x00000400),  # 26 DV_CTRL [K] (bit0 PC_CLKDIVEN, bit3 PC_SYSCLKEN)
    ("W", 0x0000B07C, 0x00000000),  # 27 MIPI PL_RG_7 [K] (b0 XCLR_LV, b1 XSTB_OP, b2 LOCKDET read-only)
)

# Appendix B rows B1-B8: temperature ADC set-up.
POST_INIT_ADC = (
    ("RMW", 0x004C, 1 << 0, 1 << 0),  # B1 adc_control.adc_en <- 1
    ("RMW", 0x004C, 1 << 1, 1 << 1),  # B2 adc_control.adc_clk_en <- 1
    ("RMW", 0x0054, 1 << 1, 1 << 1),  # B3 adc_misc_ctrl.adc_buf_cal_en <- 1
    ("D", 100),  # B4
    ("RMW", 0x005C, 1 << 1, 1 << 1),  # B5 temp_ctrl.temp_buf_en <- 1
    ("RMW", 0x005C, 1 << 0, 1 << 0),  # B6 temp_ctrl.temp_buf_cal_en <- 1
    ("D", 100),  # B7
    ("RMW", 0x004C, 0, 1 << 1),  # B8 adc_control.adc_clk_en <- 0
)
# B9-B12: photocurrent mirror for illuminance.
POST_INIT_MIRROR = (
    ("RMW", 0x0074, 1 << 0, 1 << 0),  # B9 iph_mirr_ctrl.iph_mirr_en <- 1
    ("D", 20),  # B10
    ("RMW", 0x0074, 1 << 1, 1 << 1),  # B11 iph_mirr_ctrl.iph_mirr_amp_en <- 1
    ("D", 20),  # B12
)
# B13-B18: illuminance LIFO.
POST_INIT_LIFO = (
    ("D", 1000),  # B13 (constructor)
    ("RMW", 0x000C, 1 << 0, 1 << 0),  # B14 lifo_ctrl.lifo_en <- 1
    ("D", 1000),  # B15
    ("RMW", 0x000C, 1 << 1, 1 << 1),  # B16 lifo_ctrl.lifo_out_en <- 1
    ("D", 1000),  # B17
    ("RMW", 0x000C, 1 << 2, 1 << 2),  # B18 lifo_ctrl.lifo_cnt_en <- 1
)

# B21-B33: Gen41Erc::initialize (RMW field writes, in order). Leaves the ERC configured
# but disabled (t_dropping_en = 0). The 486 LUT registers are written by RMW as the HAL does,
# not as ND's plain writes: twice the round trips, but no risk for the reserved bits.
ERC_INIT = (
    ("RMW", 0x6000, 0, 0x3),  # B21 configuration start
    ("RMW", 0x6004, 1, 0x1),  # B22 cfg_event_delay_fifo_en <- 1
    ("RMW", 0x6008, 200, 0x3FF),  # B23 erc_reference_period <- 200 us
    ("RMW", 0x600C, 10000, 0x3FFFFF),  # B24 target_event_rate <- 10000 per period
    ("RMW", 0x6028, 0b011, 0b111),  # B25 erc_en <- 1, bit1 <- 1, bit2 <- 0
    ("RMW", 0x602C, 1, 1),  # B26 open LUT write window [inferred]
    *(("RMW", 0x6800 + 4 * k, 0x08080808, 0x3F3F3F3F) for k in range(230)),  # B27
    ("RMW", 0x602C, 0, 1),  # B28
    *(("RMW", 0x6400 + 4 * k, ((2 * k + 1) << 16) | (2 * k), 0x01FF01FF) for k in range(256)),  # B29
    ("RMW", 0x6050, 0, 1),  # B30 t_dropping_en <- 0
    ("RMW", 0x6060, 0, 1),  # B31 h_dropping_en <- 0
    ("RMW", 0x6070, 0, 1),  # B32 v_dropping_en <- 0
    ("RMW", 0x6000, 1, 0x3),  # B33 configuration end
)

# B34: bias registers read back at open (low byte = factory default), in this order.
BIAS_ADDRESSES = {
    "bias_fo": 0x1004,
    "bias_hpf": 0x100C,
    "bias_diff_on": 0x1010,
    "bias_diff": 0x1014,
    "bias_diff_off": 0x1018,
    "bias_refr": 0x1020,
}

# B35-B37: reset_to_full_roi (every line enabled; 1 = disabled on this sensor).
ROI_X_ADDRESSES = tuple(0x2000 + 4 * k for k in range(40))
ROI_Y_ADDRESSES = tuple(0x4000 + 4 * k for k in range(23))
ROI_RESET = (
    *(("RMW", a, 0, 0xFFFFFFFF) for a in ROI_X_ADDRESSES),  # B35
    *(("RMW", a, 0, 0xFFFFFFFF) for a in ROI_Y_ADDRESSES[:-1]),  # B36
    ("RMW", ROI_Y_ADDRESSES[-1], 0, 0xFFFF),  # B37 rows 704-719, upper half kept
)

TRIGGER_IN_DISABLE = (("RMW", 0x7004, 0, 1 << 10),)  # B38
TRIGGER_IN_ENABLE = (("RMW", 0x7004, 1 << 10, 1 << 10),)

TIME_BASE_CTRL = 0x9008  # ro/time_base_ctrl: enable [0], mode [1] (1 external), external_mode [2] (1 master),
#                          external_mode_enable [3], us counter [10:4] (100 = 1 µs)
DIG_PAD2_CTRL = 0x0044  # pad_sync [19:16]: 0b1100 SYNC pad as output (master), 0b1111 as input (slave)


def time_base(external: bool, master: bool) -> tuple:
    """OpenEB ``TzImx636::time_base_config``: one RMW of ``time_base_ctrl`` (the enable bit
    untouched), then, for an external time base, the SYNC pad's direction."""
    value = int(external) << 1 | int(master) << 2 | int(external) << 3 | 100 << 4
    ops = (("RMW", TIME_BASE_CTRL, value, 0x7FE),)
    if external:
        ops += (("RMW", DIG_PAD2_CTRL, (0b1100 if master else 0b1111) << 16, 0xF << 16),)
    return ops


SYNC_MODES = {"standalone": time_base(False, True), "master": time_base(True, True), "slave": time_base(True, False)}
STANDALONE = SYNC_MODES["standalone"]  # B39: what the HAL sets at open

# HAL order after INIT: POST_INIT, ERC_INIT, bias reads (B34), ROI_RESET, TRIGGER_IN_DISABLE,
# STANDALONE. (B19-B20, the format selection, come only with a format other than EVT3: FORMATS.)
POST_INIT = POST_INIT_ADC + POST_INIT_MIRROR + POST_INIT_LIFO

ERC_ENABLE = (("RMW", 0x6050, 1, 1),)  # t_dropping_en <- 1 (then 0x600C is rewritten)
ERC_DISABLE = (("RMW", 0x6050, 0, 1),)
ERC_REFERENCE_PERIOD = 0x6008  # [9:0] µs
ERC_TARGET = 0x600C  # [21:0] events per period
ERC_MAX_COUNT = 640000
ERC_DEFAULT_COUNT = 10000
ERC_CONTROL = 0x6000  # [1:0] == 1: the block is running (initialised)
ERC_T_DROPPING = 0x6050  # t_dropping_en [0]
EDF_PIPELINE_CONTROL = 0x7000  # bit 1: 0 = EVT3, 1 = EVT2.1
EOI_CONTROL = 0x8000  # [7:6] output byte order: 2 = 16-bit LE (EVT3), 0 = 32-bit LE (EVT2.1)
FORMATS = {  # OpenEB TzImx636::set_output_format: two RMWs, done while not streaming
    "EVT3": (("RMW", EDF_PIPELINE_CONTROL, 0, 0x2), ("RMW", EOI_CONTROL, 2 << 6, 0x3 << 6)),
    "EVT21": (("RMW", EDF_PIPELINE_CONTROL, 0x2, 0x2), ("RMW", EOI_CONTROL, 0, 0x3 << 6)),
}

# Event trail filter / STC (OpenEB EventTrailFilter, register map stc/*).
STC_PIPELINE_CONTROL = 0xD000  # whole word: 0b101 bypassed (off), 0b001 on
STC_PARAM = 0xD004  # stc_enable [0], stc_threshold [19:1] (µs), disable_stc_cut_trail [24]
TRAIL_PARAM = 0xD008  # trail_enable [0], trail_threshold [19:1] (µs)
STC_TIMESTAMPING = 0xD00C  # prescaler [4:0], multiplier [8:5], enable_last_ts_update_at_every_event [16]
STC_INVALIDATION = 0xD0C0  # dt_fifo_timeout [23:12]
STC_INITIALIZATION = 0xD0C4  # stc_req_init [0], stc_flag_init_done [2] (write 1 to clear)
STC_THRESHOLD_US = (1_000, 100_000)  # the HAL's range, whole ms
STC_KINDS = ("trail", "stc_cut", "stc_keep")
"""``trail``: keep the first event of a burst of one polarity; ``stc_cut``: after a polarity
change drop the first event and the trail, keep the second; ``stc_keep``: drop the first event,
keep the trail. Both STC kinds drop lone events (the sensor's noise)."""
# (prescaler, multiplier, dt_fifo_timeout) per threshold in ms (1..100), the HAL's Gen4.1/IMX636 table
STC_TIMING = (
    (12, 15, 90), (10, 3, 90), (11, 5, 95), (9, 1, 102), (13, 15, 90), (11, 3, 114), (11, 3, 90),
    (12, 5, 109), (13, 9, 122), (13, 9, 90), (10, 1, 102), (14, 15, 109), (13, 7, 117), (14, 13, 127),
    (12, 3, 138), (12, 3, 90), (12, 3, 90), (14, 11, 99), (13, 5, 109), (13, 5, 109), (14, 9, 122),
    (14, 9, 122), (11, 1, 209), (11, 1, 138), (11, 1, 138), (15, 15, 147), (15, 15, 147), (14, 7, 158),
    (14, 7, 158), (15, 13, 170), (15, 13, 170), (13, 3, 185), (13, 3, 185), (13, 3, 185), (13, 3, 90),
    (13, 3, 90), (15, 11, 202), (15, 11, 99), (15, 11, 99), (15, 11, 99), (14, 5, 109), (14, 5, 109),
    (14, 5, 109), (14, 5, 109), (15, 9, 248), (15, 9, 122), (15, 9, 122), (15, 9, 122), (15, 9, 122),
    (12, 1, 280), (12, 1, 280), (12, 1, 138), (12, 1, 138), (12, 1, 138), (12, 1, 138), (16, 15, 147),
    (16, 15, 147), (16, 15, 147), (15, 7, 158), (15, 7, 158), (15, 7, 158), (15, 7, 158), (15, 7, 158),
    (16, 13, 171), (16, 13, 171), (16, 13, 171), (16, 13, 171), (16, 13, 171), (14, 3, 185), (14, 3, 185),
    (14, 3, 185), (14, 3, 185), (14, 3, 185), (16, 11, 409), (16, 11, 202), (16, 11, 202), (16, 11, 202),
    (16, 11, 202), (16, 11, 202), (16, 11, 202), (15, 5, 451), (15, 5, 223), (15, 5, 223), (15, 5, 223),
    (15, 5, 223), (15, 5, 223), (15, 5, 223), (15, 5, 223), (16, 9, 501), (16, 9, 501), (16, 9, 501),
    (16, 9, 248), (16, 9, 248), (16, 9, 248), (16, 9, 248), (16, 9, 248), (16, 9, 248), (16, 9, 248),
    (13, 1, 564), (13, 1, 564),
)

# Anti-flicker (AFK) block, OpenEB register map `afk/*` and AntiFlickerFilter::enable.
AFK_PIPELINE_CONTROL = 0xC000  # 0b101 = off (also while configuring), 0b001 = on
AFK_PARAM = 0xC004  # counter_low [2:0], counter_high [5:3], invert [6] (0 = band-stop)
AFK_FILTER_PERIOD = 0xC008  # min_cutoff_period [7:0], max_cutoff_period [15:8] (128 µs units), inverted_duty_cycle [19:16]
AFK_INVALIDATION = 0xC0C0  # dt_fifo_wait_time [11:0] (the HAL writes 1630 on the IMX636)
AFK_INITIALIZATION = 0xC0C4  # afk_flag_init_done [2]
AFK_BAND_HZ = (50, 520)  # the HAL's supported frequencies
AFK_DEFAULTS = {"inverted_duty_cycle": 8, "counter_high": 6, "counter_low": 4}  # 50 % duty, hysteresis

ADC_CONTROL = 0x004C  # adc_en [0], adc_clk_en [1], adc_start [2]
ADC_STATUS = 0x0050  # adc_dac_dyn [9:0], adc_done_dyn [11]
ADC_MISC_CTRL = 0x0054  # adc_buf_cal_en [1], adc_temp [12]
TEMPERATURE_C_PER_STEP, TEMPERATURE_OFFSET_C = 0.190, -56.0  # the HAL's get_temperature: 0.190 x dac - 56
DIG_CTRL = 0x900C  # ro/dig_ctrl: dig_crop_enable [2:0] (5 on, 0 off), dig_crop_reset_orig [4]
DIG_START_POS = 0x9010  # dig_crop_start_x [10:0], dig_crop_start_y [25:16]
DIG_END_POS = 0x9014  # dig_crop_end_x [10:0], dig_crop_end_y [25:16] (the last pixel kept)
LIFO_CONTROL = 0x000C  # lifo_en [0], lifo_out_en [1], lifo_cnt_en [2]
LIFO_STATUS = 0x0010  # lifo_ton [28:0] (the HAL keeps [26:0]), lifo_ton_valid [29]


def illuminance_lux(counter: int) -> float:
    """The HAL's light level from the LIFO's on-time counter (``TzImx636::get_illumination``):
    ``10 ** (3.5 - log10(0.37 * counter / 100))`` lux."""
    return 10.0 ** (3.5 - math.log10(0.37 * counter / 100.0))


def lifo_counter(lux: float) -> float:
    """The LIFO on-time count whose :func:`illuminance_lux` is ``lux`` (its inverse)."""
    return 100.0 * 10.0 ** (3.5 - math.log10(lux)) / 0.37


CHIP_ID_ADDRESS = 0x0014
CHIP_ID = 0xA0401806
VARIANT_ADDRESS = 0xF128  # bits [1:0]: 0 = IMX636, 2 = IMX646
