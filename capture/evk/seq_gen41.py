"""EVK3-HD with Gen4.1 (``psee,ccam5_gen41``) register sequences, as data (best effort).

Transcribed from ``docs/evk-usb.md`` Appendix E (``gen41_evk3_*``); the spec's compressed rows
"A ... B (step 4, N regs)" are expanded here into the N plain writes they stand for. Op format
as in :mod:`capture.evk.seq_imx636`. After INIT the HAL does (section 3.14): illuminance
mirror + LIFO (IMX636 rows B9-B18), ERC initialise and enable, ROI reset, trigger disabled,
standalone time base; those reuse the IMX636 tables (same register architecture).
"""

from .seq_imx636 import (  # same register architecture as the IMX636
    ROI_RESET,
    ROI_X_ADDRESSES,
    ROI_Y_ADDRESSES,
    TRIGGER_IN_DISABLE,
)

__all__ = ["INIT", "START", "STOP", "DESTROY", "ROI_RESET", "ROI_X_ADDRESSES", "ROI_Y_ADDRESSES",
           "TRIGGER_IN_DISABLE", "TRIGGER_IN_ENABLE", "CHIP_IDS", "BIAS_REGISTERS"]

INIT = (
    ("W", 0x0000001C, 0x00000001),  # 1 unnamed (not in public maps)
    # Digital INIT
    ("W", 0x00000064, 0x00000001),  # 2 unnamed
    ("W", 0x0000B074, 0x00000002),  # 3 MIPI PL_RG_5 [K] (PLL input divider)
    ("W", 0x0000B078, 0x000000A0),  # 4 MIPI PL_RG_6 [K] (PLL feedback divider)
    ("W", 0x00000000, 0x10006402),  # 5 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x10001402),  # 6 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x10001442),  # 7 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x0000B068, 0x00000004),  # 8 MIPI PL_RG_2 [K] (bit2 ENDET_OP)
    ("W", 0x0000B07C, 0x00000003),  # 9 MIPI PL_RG_7 [K] (b0 XCLR_LV, b1 XSTB_OP, b2 LOCKDET read-only)
    ("D", 1000),  # 10
    ("W", 0x00000000, 0x50001442),  # 11 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x5000144A),  # 12 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x5000140A),  # 13 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x5000640A),  # 14 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x5000644A),  # 15 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x0000B080, 0x00000077),  # 16 D-PHY TCLKPOST [K]
    ("W", 0x0000B084, 0x0000000F),  # 17 D-PHY TCLKPRE [K]
    ("W", 0x0000B088, 0x00000037),  # 18 D-PHY TCLKPREPARE [K]
    ("W", 0x0000B08C, 0x00000037),  # 19 D-PHY TCLKTRAIL [K]
    ("W", 0x0000B090, 0x000000DF),  # 20 D-PHY TCLKZERO [K]
    ("W", 0x0000B094, 0x00000057),  # 21 D-PHY THSEXIT [K]
    ("W", 0x0000B098, 0x00000037),  # 22 D-PHY THSPREPARE [K]
    ("W", 0x0000B09C, 0x00000067),  # 23 D-PHY THSZERO [K]
    ("W", 0x0000B0A0, 0x00000037),  # 24 D-PHY THSTRAIL [K]
    ("W", 0x0000B0A4, 0x0000002F),  # 25 D-PHY TLPX [K]
    ("W", 0x0000B0AC, 0x00000028),  # 26 D-PHY TXCLKESC_FREQ [K]
    ("W", 0x0000B0CC, 0x00000001),  # 27 MIPI DPHY_PLL_DIV [K]
    ("W", 0x0000B000, 0x000002D8),  # 28 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("W", 0x0000B004, 0x0000008A),  # 29 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("W", 0x0000B01C, 0x00000030),  # 30 unnamed (MIPI block)
    ("W", 0x0000B020, 0x00002000),  # 31 mipi_csi/mipi_packet_size [R]
    ("W", 0x0000B02C, 0x000000FF),  # 32 mipi_csi/mipi_line_blanking [R]
    ("W", 0x0000B030, 0x00003E80),  # 33 mipi_csi/mipi_frame_blanking [R]
    ("W", 0x0000B028, 0x00000FA0),  # 34 mipi_csi/mipi_frame_period [R]
    ("W", 0x0000B040, 0x00000007),  # 35 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000A000, 0x00000101),  # 36 unnamed (analog power block)
    ("D", 200),  # 37
    ("W", 0x0000A008, 0x00002405),  # 38 unnamed (analog power block)
    ("D", 200),  # 39
    ("W", 0x0000A004, 0x00000101),  # 40 unnamed (analog power block)
    ("D", 200),  # 41
    ("W", 0x0000A020, 0x00000170),  # 42 unnamed (analog power block)
    ("D", 200),  # 43
    ("W", 0x0000B040, 0x0000000F),  # 44 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B004, 0x0000008A),  # 45 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("D", 200),  # 46
    ("W", 0x0000B0C8, 0x00000003),  # 47 MIPI DPHY_POWER [K] (b0 BIASEN, b1 LPREGEN)
    ("D", 200),  # 48
    ("W", 0x0000B044, 0x00000001),  # 49 MIPI_STREAM [K]
    ("W", 0x0000B000, 0x000002D9),  # 50 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("W", 0x00009008, 0x00000640),  # 51 ro/time_base_ctrl [R]
    ("W", 0x00008000, 0x0001E005),  # 52 eoi/pipeline control [R][K] (bits7:6 byte order)
    ("W", 0x00007008, 0x00000001),  # 53 unnamed (EDF block)
    ("W", 0x00007000, 0x00070001),  # 54 edf/pipeline_control [R] (bit1 format: 0=EVT3, 1=EVT2.1)
    ("W", 0x00006008, 0x000000C8),  # 55 erc/reference_period [R]
    ("W", 0x0000600C, 0x00000FA0),  # 56 erc/td_target_event_rate [R]
    ("W", 0x00006004, 0x00000001),  # 57 erc/in_drop_rate_control [R]
    ("W", 0x0000602C, 0x00000001),  # 58 erc/Reserved_602C [R]
    *(("W", 0x00006800 + 4 * k, 0x08080808) for k in range(230)),  # 59 erc/Reserved_6800.. (ERC LUT) [R]
    ("W", 0x0000602C, 0x00000000),  # 60 erc/Reserved_602C [R]
    *(("W", 0x00006800 + 4 * k, 0x00000000) for k in range(230)),  # 61 erc/Reserved_6800.. (ERC LUT) [R]
    *(("W", 0x00006400 + 4 * k, ((2 * k + 1) << 16) + 2 * k) for k in range(256)),  # 62 erc/t_drop_lut_00.. [R]
    ("W", 0x00006080, 0x03020100),  # 63 erc/h_drop_lut [R]
    ("W", 0x00006084, 0x07060504),  # 64 erc/h_drop_lut [R]
    ("W", 0x00006088, 0x0B0A0908),  # 65 erc/h_drop_lut [R]
    ("W", 0x0000608C, 0x0F0E0D0C),  # 66 erc/h_drop_lut [R]
    ("W", 0x00006090, 0x13121110),  # 67 erc/h_drop_lut [R]
    ("W", 0x00006094, 0x17161514),  # 68 erc/h_drop_lut [R]
    ("W", 0x00006098, 0x1B1A1918),  # 69 erc/h_drop_lut [R]
    ("W", 0x0000609C, 0x1F1E1D1C),  # 70 erc/h_drop_lut [R]
    ("W", 0x000060C0, 0x03020100),  # 71 erc/v_drop_lut [R]
    ("W", 0x000060C4, 0x07060504),  # 72 erc/v_drop_lut [R]
    ("W", 0x000060C8, 0x0B0A0908),  # 73 erc/v_drop_lut [R]
    ("W", 0x000060CC, 0x0F0E0D0C),  # 74 erc/v_drop_lut [R]
    ("W", 0x000060D0, 0x13121110),  # 75 erc/v_drop_lut [R]
    ("W", 0x000060D4, 0x17161514),  # 76 erc/v_drop_lut [R]
    ("W", 0x000060D8, 0x1B1A1918),  # 77 erc/v_drop_lut [R]
    ("W", 0x000060DC, 0x1F1E1D1C),  # 78 erc/v_drop_lut [R]
    ("W", 0x00006028, 0x00000003),  # 79 erc/erc_enable [R]
    ("W", 0x00006050, 0x00000000),  # 80 erc/t_dropping_control [R]
    ("W", 0x00006060, 0x00000000),  # 81 erc/h_dropping_control [R]
    ("W", 0x00006070, 0x00000000),  # 82 erc/v_dropping_control [R]
    ("W", 0x00006000, 0x00155401),  # 83 erc/Reserved_6000 [R]
    ("W", 0x0000D000, 0x00000005),  # 84 stc/pipeline_control [R]
    ("W", 0x0000C000, 0x00000005),  # 85 afk/pipeline_control [R]
    ("W", 0x00009000, 0x00000208),  # 86 ro/readout_ctrl [R][K] (0x200 = digital pipe only)
    ("W", 0x00007008, 0x00000001),  # 87 unnamed (EDF block)
    ("W", 0x00007000, 0x00070001),  # 88 edf/pipeline_control [R] (bit1 format: 0=EVT3, 1=EVT2.1)
    ("W", 0x00008000, 0x0001E085),  # 89 eoi/pipeline control [R][K] (bits7:6 byte order)
    ("W", 0x00009008, 0x00000644),  # 90 ro/time_base_ctrl [R]
    ("W", 0x00000004, 0xF0005442),  # 91 roi_ctrl [R]
    # Analog INIT
    ("W", 0x00000004, 0xF0005042),  # 92 roi_ctrl [R]
    ("W", 0x0000002C, 0x00200224),  # 93 unnamed; 'analog start/stop' (bit10) [I]
    ("W", 0x0000A000, 0x00000101),  # 94 unnamed (analog power block)
    ("W", 0x0000A000, 0x000000A1),  # 95 unnamed (analog power block)
    ("D", 200),  # 96
    ("R", 0x0000A000),  # 97 unnamed (analog power block); HAL discards (expect 0x000002A1, mask 0x00000200)
    ("W", 0x0000A008, 0x00002405),  # 98 unnamed (analog power block)
    ("D", 200),  # 99
    ("R", 0x0000A008),  # 100 unnamed (analog power block); HAL discards (expect 0x00082405, mask 0x00080000)
    ("W", 0x0000A004, 0x00000101),  # 101 unnamed (analog power block)
    ("W", 0x0000A004, 0x000000A1),  # 102 unnamed (analog power block)
    ("D", 200),  # 103
    ("R", 0x0000A004),  # 104 unnamed (analog power block); HAL discards (expect 0x000002A1, mask 0x00000200)
    ("W", 0x0000A020, 0x00000170),  # 105 unnamed (analog power block)
    ("W", 0x0000A020, 0x00000160),  # 106 unnamed (analog power block)
    ("D", 200),  # 107
    ("W", 0x0000A008, 0x00082401),  # 108 unnamed (analog power block)
    ("W", 0x0000004C, 0x00007141),  # 109 adc_control [R]
    ("W", 0x00000054, 0x00000210),  # 110 adc_misc_ctrl [R]
    ("W", 0x00000008, 0x60000000),  # 111 unnamed
    ("W", 0x00001104, 0x00000001),  # 112 unnamed (bias generator)
    ("W", 0x0000A010, 0x0000A06B),  # 113 unnamed (analog power block)
    ("D", 300),  # 114
    ("W", 0x00001100, 0x00000004),  # 115 bias/bgen_ctrl [R]
    ("D", 200),  # 116
    ("R", 0x0000A010),  # 117 unnamed (analog power block); HAL discards (expect 0x0180A06B, mask 0x00800000)
    ("W", 0x0000A010, 0x0180A063),  # 118 unnamed (analog power block)
    ("W", 0x0000A00C, 0x00000404),  # 119 unnamed (analog power block)
    ("W", 0x0000A00C, 0x00000405),  # 120 unnamed (analog power block)
    ("D", 1000),  # 121
    ("R", 0x0000A00C),  # 122 unnamed (analog power block); HAL discards (expect 0x00020405, mask 0x00020000)
    ("W", 0x0000A00C, 0x00020401),  # 123 unnamed (analog power block)
    ("D", 300),  # 124
    ("W", 0x00000070, 0x00400000),  # 125 unnamed (analog power)
    ("W", 0x0000006C, 0x0EE47117),  # 126 unnamed (analog power)
    ("D", 100),  # 127
    ("W", 0x0000006C, 0x0EE4711F),  # 128 unnamed (analog power)
    ("D", 100),  # 129
    ("W", 0x00000070, 0x00480000),  # 130 unnamed (analog power)
    ("D", 1000),  # 131
    ("W", 0x00001044, 0x01A98A7C),  # 132 bias reqpux [N]
    ("W", 0x00001040, 0x01A98A94),  # 133 bias reqpuy [N]
    ("W", 0x00001048, 0x01A98B94),  # 134 bias sendreqpdy [N]
    ("W", 0x0000101C, 0x01A1575B),  # 135 bias inv [N]
    ("W", 0x00001050, 0x01A1B251),  # 136 bias unknown_2 [N]
    ("W", 0x00001020, 0x01A9CD44),  # 137 bias/bias_refr [R]
    ("W", 0x0000100C, 0x01A1FF00),  # 138 bias/bias_hpf [R]
    ("W", 0x00001018, 0x01A13734),  # 139 bias/bias_diff_off [R]
    ("W", 0x00001010, 0x01A16373),  # 140 bias/bias_diff_on [R]
    ("W", 0x00001014, 0x01A15050),  # 141 bias/bias_diff [R]
    ("W", 0x00001004, 0x01A1E84A),  # 142 bias/bias_fo [R]
    ("W", 0x00001008, 0x01210000),  # 143 bias (unnamed)
    ("W", 0x00001000, 0x01A1C469),  # 144 bias pr [N]
    ("W", 0x0000104C, 0x01A19278),  # 145 bias unknown_1 [N]
    ("W", 0x00001100, 0x00000005),  # 146 bias/bgen_ctrl [R]
    ("W", 0x0000002C, 0x0022C724),  # 147 unnamed; 'analog start/stop' (bit10) [I]
    ("W", 0x00000018, 0x00000200),  # 148 spare0 / SPARE_CTRL0 [R][K]
    ("R", 0x00000014),  # 149 chip id (expect 0xA0301003 Gen4.1); HAL discards (expect 0xA0301003, mask 0xFFFFFFFF)
)

START = (
    ("W", 0x0000B000, 0x000002D9),  # 1 mipi_csi/mipi_control [R] (bit0 csi enable)
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
    ("R", 0x0000C000),  # 3 afk/pipeline_control [R]; HAL discards (expect 0x00000005, mask 0x00000007)
    ("W", 0x0000C000, 0x00000002),  # 4 afk/pipeline_control [R]
    ("W", 0x00009028, 0x00000002),  # 5 ro/ro_ctrl (RO_LP_CTRL) [R][K] (bit1 output_disable)
    ("W", 0x0000C000, 0x00000005),  # 6 afk/pipeline_control [R]
    ("D", 1000),  # 7
    ("RMW", 0x00009008, 0x00000644, 0x00000001),  # 8 ro/time_base_ctrl [R]
    ("W", 0x0000B000, 0x000002D8),  # 9 mipi_csi/mipi_control [R] (bit0 csi enable)
    ("D", 300),  # 10
    ("R", 0x0000B000),  # 11 mipi_csi/mipi_control [R] (bit0 csi enable); HAL discards (expect 0x000002DC, mask 0x000007FF)
)

DESTROY = (
    # Analog DESTROY
    ("W", 0x00000070, 0x00400000),  # 1 unnamed (analog power)
    ("W", 0x0000006C, 0x0EE47114),  # 2 unnamed (analog power)
    ("D", 500),  # 3
    ("W", 0x0000A00C, 0x00000400),  # 4 unnamed (analog power block)
    ("D", 500),  # 5
    ("W", 0x0000A010, 0x00008068),  # 6 unnamed (analog power block)
    ("D", 200),  # 7
    ("W", 0x00001104, 0x00000000),  # 8 unnamed (bias generator)
    ("D", 200),  # 9
    ("W", 0x0000A020, 0x00000060),  # 10 unnamed (analog power block)
    ("D", 200),  # 11
    ("W", 0x0000A004, 0x000002A0),  # 12 unnamed (analog power block)
    ("D", 200),  # 13
    ("W", 0x0000A008, 0x00002400),  # 14 unnamed (analog power block)
    ("D", 200),  # 15
    ("W", 0x0000A000, 0x000002A0),  # 16 unnamed (analog power block)
    # Digital DESTROY
    ("W", 0x0000B044, 0x00000000),  # 17 MIPI_STREAM [K]
    ("R", 0x0000B044),  # 18 MIPI_STREAM [K]; HAL discards (expect 0x00000000, mask 0x00000003)
    ("W", 0x0000B004, 0x0000000A),  # 19 MIPI ESCAPE_CTRL [K] (bit7 escape clk en)
    ("W", 0x0000B040, 0x0000000E),  # 20 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B0C8, 0x00000000),  # 21 MIPI DPHY_POWER [K] (b0 BIASEN, b1 LPREGEN)
    ("W", 0x0000B040, 0x00000006),  # 22 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x0000B040, 0x00000004),  # 23 MIPI_POWER [K] (b0 RST_W, b1 XCLR_LV, b2 XCLR_MV, b3 BCIF_EN)
    ("W", 0x00000000, 0x50006442),  # 24 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x00000000, 0x10006442),  # 25 GLOBAL_CTRL [K] (bit3 SYS_CLK_SWITCH_SEL, bit30 SYS_CLK_EN)
    ("W", 0x0000B07C, 0x00000000),  # 26 MIPI PL_RG_7 [K] (b0 XCLR_LV, b1 XSTB_OP, b2 LOCKDET read-only)
)

CHIP_IDS = (0xA0301003, 0xA0301002)

# Absolute 0-255 biases: (register, recommended min, max).
BIAS_REGISTERS = {
    "bias_fo": (0x1004, 0x2D, 0x6E),
    "bias_hpf": (0x100C, 0x00, 0x78),
    "bias_diff_on": (0x1010, 0x00, 0x8C),
    "bias_diff": (0x1014, 0x34, 0x64),
    "bias_diff_off": (0x1018, 0x19, 0xFF),
    "bias_refr": (0x1020, 0x14, 0x64),
}

TRIGGER_IN_ENABLE = (  # the HAL's order (Gen41TzTriggerEvent::enable): pad first, then the edf bit
    ("RMW", 0x0044, 0xF << 12, 0xF << 12),  # dig_pad2_ctrl [15:12] <- 0xF (Gen4.1 class only)
    ("RMW", 0x7004, 1 << 10, 1 << 10),
)
