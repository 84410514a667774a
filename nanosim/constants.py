"""Physical and bench constants, each with its source (paper numbers: :mod:`nanosim.paper`).

Units are in the names. "Controller volts" are the controller's output before
the x20 piezo amplifier; "sensor volts" are the capacitance-gauge output
(5 um/V). Paper = Robust Control of a Parallel-Kinematic Nanopositioner,
J. Dyn. Sys., Meas., Control 130 (2008), DOI 10.1115/1.2936861.
"""
from __future__ import annotations

import numpy as np

__all__ = ["CONTROL_RATE_HZ", "CONTROL_PERIOD_S", "AMPLIFIER_GAIN", "COMMAND_RANGE_V", "PIEZO_MAX_V",
           "PIEZO_FREE_STROKE_M", "PIEZO_BLOCKING_FORCE_N", "PIEZO_STIFFNESS_N_PER_M",
           "PIEZO_FORCE_PER_PIEZO_V", "CREEP_PER_DECADE", "CREEP_TAU_MIN_S", "CREEP_TAU_MAX_S",
           "CREEP_STAGES_PER_DECADE", "CREEP_REFERENCE_STEP_PIEZO_V",
           "COMPUTATION_DELAY_SAMPLES", "AMPLIFIER_BANDWIDTH_HZ", "PIEZO_CAPACITANCE_F", "CHARGE_CROSSOVER_HZ",
           "CHARGE_RESIDUAL_HYSTERESIS", "CHARGE_SHUNT_OHM",
           "AMPLIFIER_NOISE_V", "DAC_WHITE_NOISE_V", "DAC_BITS", "DAC_FULL_SCALE_V", "DAC_CENTER_V",
           "BROADBAND_INPUT_NOISE_V",
           "THERMAL_EXPANSION_DIFF_PER_K", "THERMAL_LOOP_LENGTH_M", "THERMAL_DRIFT_TAU_S", "THERMAL_AIR_TAU_S",
           "THERMAL_DRIFT_K_RMS",
           "THERMAL_DRIFT_K_BOUNDS", "DAC_FLICKER_CORNER_HZ", "GAUGE_BANDWIDTH_HZ",
           "GAUGE_FILTER_ORDER", "FLOOR_ACCEL_PSD_M2_S4_HZ", "FLOOR_VC_C_VELOCITY_UM_S", "FLOOR_TABLE_PLATEAU",
           "SENSOR_UM_PER_V", "SENSOR_RANGE_UM",
           "SENSOR_NOISE_NM_RMS_1KHZ",
           "ADC_BITS", "ADC_FULL_SCALE_V", "ADC_LSB_V", "ADC_LSB_NM", "JACOBIAN_J",
           "STATIC_GAIN_SCALE_UM_PER_V", "AXES", "ACTUATORS", "DEFAULT_REDUCED_ORDER", "DEFAULT_DAMPING_ZETA",
           "DEFAULT_PRBS_BANDS_HZ",
           "DEFAULT_DAMPING_LOWPASS_HZ"]

# --- control loop (paper Sec. 3) --------------------------------------------
CONTROL_RATE_HZ = 4000.0
CONTROL_PERIOD_S = 1.0 / CONTROL_RATE_HZ

# --- piezo and amplifier (paper Sec. 2, APA35XS datasheet values quoted there)
AMPLIFIER_GAIN = 20.0                      # piezo volts per controller volt
COMMAND_RANGE_V = (-1.0, 7.5)              # controller volts (paper Sec. 4)
PIEZO_MAX_V = 150.0                        # piezo volts
PIEZO_FREE_STROKE_M = 55e-6                # at 150 V
PIEZO_BLOCKING_FORCE_N = 27.0              # at 150 V
# Stack stiffness = blocking force / free stroke (linear piezo model).
PIEZO_STIFFNESS_N_PER_M = PIEZO_BLOCKING_FORCE_N / PIEZO_FREE_STROKE_M   # 4.909e5 N/m
# Blocked force per piezo volt; the actuator force on the tendon is
# F = PIEZO_FORCE_PER_V * v_free, with v_free the hysteretic "free-strain voltage".
PIEZO_FORCE_PER_PIEZO_V = PIEZO_BLOCKING_FORCE_N / PIEZO_MAX_V         # 0.18 N/V

# --- piezo creep (nanosim.plant.piezo) ----------------------------------------
# Logarithmic creep, x(t) = x(t0) (1 + gamma log10(t / t0)), t0 = 0.1 s: PI Piezo Tutorial (Cat. 118,
# p. 4-18; physikinstrumente.com/tutorial/4_21.html) gives gamma = 0.01-0.02 per decade for stacks
# (Jung & Gweon, Rev. Sci. Instrum. 71, 1896 (2000)). The piezo's activation voltage is calibrated
# within that range to the open-loop creep of the paper's Fig. 15 move: 0.015, the middle of the range
# (not a bound). The same gamma sets the linear Kelvin-Voigt creep law (1 ms to 100 s, two stages per
# decade; the law has no time constant of its own, the range covers every record the simulator runs).
# CREEP_TAU_MIN_S is also the creep's onset, attempt rate nu = V_a / CREEP_TAU_MIN_S (below 1 ms the
# amplifier and the mechanics dominate the response).
CREEP_PER_DECADE = 0.015
CREEP_TAU_MIN_S = 1e-3
CREEP_TAU_MAX_S = 100.0
CREEP_STAGES_PER_DECADE = 2
# Fig. 15's move: from the stage's home to the gauge origin, solve(G0, -home) on the nominal stage =
# 2.77-2.93 controller V on the three actuators, 55-59 piezo V; their mean, the step the creep rate refers to.
CREEP_REFERENCE_STEP_PIEZO_V = 57.0

# --- the bench loop (nanosim.plant.electronics; mjcf/SOURCES.md items 4-6) -------
# Computation delay between the controller's output and the DAC update, whole samples. The UMAC
# reads the ADC at the servo interrupt, computes the controller and writes the DAC in the same
# servo cycle (a fraction of a sample later), so the command acts from within the period it was
# computed in: 0 whole samples (physics of the bench; mjcf/SOURCES.md item 6 estimates the loop
# delay as 1 sample + 1/2 sample ZOH and recommends 1 whole sample, range 0.5-2: the conservative
# reading). Appendix A's right-half-plane zeros near 2/T do not separate 0 from 1 (the simulated
# identification shows such zeros either way). Consequences, not reasons: with 1, the default
# damping-loop design (400 Hz low-pass) is unstable at ~277 Hz; the exported robust LQG is checked
# stable, with mixed mu < 1, for 0-1 extra sample (nanosim.design.uncertainty.STAGE_UNCERTAINTY).
# 1 and 2 are ablation rows.
COMPUTATION_DELAY_SAMPLES = 0
# Amplifier small-signal bandwidth into the APA35XS capacitance (first order). PiezoDrive PD200
# (gain 20): 7.4 kHz small-signal into 10 uF, i.e. R_out ~ 2.2 ohm (Dehaeze, test-bench-pd200);
# into an APA35XS (0.05-0.5 uF, estimated) the RC pole is above 100 kHz and the amplifier's own
# bandwidth dominates: >= 10 kHz; 10 kHz is the conservative end (a lag of 16 us).
AMPLIFIER_BANDWIDTH_HZ = 10e3
# --- the charge amplifier (ElectronicsConfig(drive="charge"), nanosim.plant.charge_drive) ----------------
# APA35XS capacitance: estimate [E] 0.2 uF in [0.05, 0.5] uF (no Cedrat datasheet value in reach; the range
# of the amplifier-bandwidth estimate above, a small multilayer stack of the APA-XS class).
PIEZO_CAPACITANCE_F = 0.2e-6
# Crossover below which the charge drive is a voltage drive, f_c = 1 / (2 pi R_p C_p) (Fleming & Moheimani,
# Rev. Sci. Instrum. 76, 073707 (2005); Fleming & Leang 2014, Ch. 12): as low as the shunt allows, since the
# hysteresis returns below it; the shunt's leakage and the settling of a DC move (time constant R_p C_p) bound
# it from below. Usual choice [E] 0.01-1 Hz; 0.1 Hz, a decade below the slowest paper loop (Fig. 14, 0.5 Hz),
# and a 1.6 s settling of the DC level.
CHARGE_CROSSOVER_HZ = 0.1
# The shunt that sets it: R_p = 1 / (2 pi f_c C_p) = 8 Mohm (R_s C_s = R_p C_p).
CHARGE_SHUNT_OHM = 1.0 / (2.0 * np.pi * CHARGE_CROSSOVER_HZ * PIEZO_CAPACITANCE_F)
# Fraction of the voltage drive's hysteresis left under charge drive: "a 5-fold reduction" (Fleming & Leang
# 2014, Ch. 12, citing Ge & Jouaneh 1996 and Fleming 2010); 84-90 % less at 0.05-10 Hz (Zhang et al.,
# Electron. Lett. 48, 697 (2012)). 0.2 in [0.1, 0.2].
CHARGE_RESIDUAL_HYSTERESIS = 0.2
# Amplifier noise, referred to its input (controller V per sample over the 2 kHz Nyquist band):
# PD200 0.7 mV rms at the output into 10 uF (ENBW 1.57 x 7.4 kHz) -> 6.5 uV/sqrt(Hz) at the
# piezo -> 0.33 uV/sqrt(Hz) at the input -> 14.5 uV rms over 2 kHz.
AMPLIFIER_NOISE_V = 14.5e-6
# DAC: the UMAC's analog-output board (the paper names the UMAC and its ACC-28E 16-bit ADC, not the DAC
# board; the UMAC analog servo interface ACC-24E2A has 18-bit DACs over +/-10 V, mjcf/SOURCES.md item 6;
# no datasheet of the paper's board in reach). Resolution bounded to [16, 18] bits over +/-10 V; 18 bits:
# LSB 76 uV, 22 uV rms when dithered. The paper's own pair of sigmas bounds it from the other side: a
# dithered 16-bit DAC over +/-10 V (LSB 305 uV, 88 uV rms) is three times the ~30 uV of broadband input
# noise that its closed-loop 1.89 nm leaves room for. Undithered (the other input noise is below one LSB)
# the quantizer in the loop is no white source; its closed-loop share is measured by the noise budget
# (nanosim.experiments.resolution, "DAC quantization").
DAC_BITS = 18
DAC_FULL_SCALE_V = 10.0
DAC_CENTER_V = 0.0
# DAC electrical noise, the standard electronic-noise spectrum e_n^2 (1 + f_c / f), white part per sample
# over the 2 kHz Nyquist band: e_n sqrt(fs / 2). e_n = 120 nV/sqrt(Hz): the output noise density of a
# monolithic 16-bit +/-10 V DAC with its output amplifier (Analog Devices AD669 datasheet, "output noise
# voltage density 120 nV/rtHz"), the class of converter on a UMAC analog-output board; 18-bit
# converters of that class (AD5781, 7.5 nV/rtHz plus the +/-10 V output stage) are quieter, so this is
# the upper end. 120e-9 * sqrt(2000) = 5.37 uV.
DAC_WHITE_NOISE_V = 120e-9 * np.sqrt(CONTROL_RATE_HZ / 2)
# Every broadband input-side source per sample in all (controller V): DAC white noise, the DAC's
# quantization as if dithered (LSB / sqrt(12)) and the amplifier's input-referred noise, added in
# variance (the level a model-based design can take as its input noise).
BROADBAND_INPUT_NOISE_V = float(np.sqrt(DAC_WHITE_NOISE_V ** 2 + (2 * DAC_FULL_SCALE_V / 2 ** DAC_BITS) ** 2 / 12
                                        + AMPLIFIER_NOISE_V ** 2))
# 1/f corner of that noise: estimate [E] in [1, 100] Hz, typical of precision op-amp/reference
# output stages (the AD669 datasheet gives the density at 1 kHz only); 10 Hz, the geometric middle.
DAC_FLICKER_CORNER_HZ = 10.0
# Capacitive gauge (ADE 2805 probe + 4810 module) output filter: not in the paper; gauging
# modules of that class offer ~100 Hz ... 5 kHz (Queensgate NanoSensor: 50/500/5000 Hz); the
# paper's "0.3 nm at 1 kHz" is a noise specification. 5 kHz, 2-pole Butterworth (mjcf/SOURCES.md item 5):
# estimate [E] in [0.5, 5] kHz, the widest setting (no ADE 4810 datasheet in reach).
GAUGE_BANDWIDTH_HZ = 5000.0
GAUGE_FILTER_ORDER = 2
# Floor vibration: table-top acceleration PSD, (m/s^2)^2/Hz, white to the Nyquist frequency, per
# axis: estimate [E] in [1e-12, 1e-9] (mjcf/SOURCES.md item 9). Its stated basis, a VC-C floor
# (12.5 um/s in 1/3-octave bands, Gordon/Ungar, IEST-RP-CC012) through a table plateau of 0.01,
# gives 3e-11 only at ~11 Hz; at the 175-245 Hz modes it gives 4.7e-10-6.5e-10, and 3e-11 there is
# a transmissibility of ~0.0025 (between an ideal 1.5 Hz isolator's 0.0017 and the plateau). At
# 4.7e-10 the floor's share of the closed-loop table sigma is 0.53-0.64 nm instead of 0.13-0.23 nm,
# measured on seeds 0-4 (mjcf/README.md, "Estimates the predictions depend on").
FLOOR_ACCEL_PSD_M2_S4_HZ = 3e-11
# The stated basis of that level (item 9): a vibration-criterion floor, rms velocity per 1/3-octave band
# (VC-C: 12.5 um/s; Gordon/Ungar, IEST-RP-CC012), through the isolated table's transmissibility plateau
# (0.01, -40 dB); nanosim.plant.floor.vc_accel_psd turns it into an acceleration PSD at a frequency.
FLOOR_VC_C_VELOCITY_UM_S = 12.5
FLOOR_TABLE_PLATEAU = 0.01

# --- low-frequency drift: thermal expansion of the actuated legs (nanosim.plant.electronics) ----------
# Each leg's temperature deviation follows the chamber air near it: the air's temperature fluctuation is a
# first-order (Ornstein-Uhlenbeck) process, and the leg follows it through its own heat diffusion, a
# first-order lag; the leg's temperature is therefore a second-order process whose spectrum falls as f^-4
# above both corners. Its elongation is the differential
# expansion of the aluminium frame (7075-T6, CTE 23.4e-6/K; ASM handbook) against the APA35XS actuator
# (steel shell, 12e-6/K; Cedrat APA datasheet class) over the actuator's mounted length (hinge centre to
# hinge centre, the actuator's length_m in nanosim.plant.geometry, 15 mm); it lengthens the actuator's
# stroke like a free-strain change, referred to controller volts by the free stroke per volt.
THERMAL_EXPANSION_DIFF_PER_K = 23.4e-6 - 12e-6
THERMAL_LOOP_LENGTH_M = 15.0e-3
# The leg's lag: the diffusion time d^2 / a of a d = 5 mm aluminium link (a = 9.7e-5 m^2/s, 7075 thermal
# diffusivity) is 0.26 s; estimate [E] in [0.1, 1] s. The air's correlation time: the turnover of the
# convection in the sealed chamber, estimate [E] in [0.1, 3] s; 0.5 s.
THERMAL_DRIFT_TAU_S = 0.26
THERMAL_AIR_TAU_S = 0.5
# rms temperature fluctuation of each leg, K: the ONE level calibrated to the paper, the open-loop probe
# sigma at rest, 11.4 nm (tools/fit_drift_level.py: mean variance over the X and Y probes of 20 stages
# on streams of their own), with every broadband source at its datasheet level. Calibrated within
# [THERMAL_DRIFT_K_BOUNDS]: a sealed chamber on an isolated table in an air-conditioned laboratory, whose
# air holds +/-0.1 K (HVAC class), at most that; at least 1 mK.
THERMAL_DRIFT_K_RMS = 0.0594
THERMAL_DRIFT_K_BOUNDS = (1e-3, 0.1)

# --- capacitance gauges and ADC (paper Sec. 2-3) -----------------------------
SENSOR_UM_PER_V = 5.0
SENSOR_RANGE_UM = 50.0                     # +/-
SENSOR_NOISE_NM_RMS_1KHZ = 0.3
ADC_BITS = 16
ADC_FULL_SCALE_V = 10.0                    # +/-10 V over 2**16 counts
# One count = 20 V / 2**16 = 0.305 mV = 1.53 nm at 5 um/V ("about 1.5 nm").
ADC_LSB_V = 2 * ADC_FULL_SCALE_V / 2**ADC_BITS
ADC_LSB_NM = ADC_LSB_V * SENSOR_UM_PER_V * 1e3

# --- kinematics (paper Eq. 2) ------------------------------------------------
JACOBIAN_J = np.array([[-2.022, -1.190, 3.212],
                       [2.542, -3.022, 0.480],
                       [0.990, 0.990, 0.990]])
# Target static gain, controller volts -> um: 3.0 um/V * J (G_AX(0) = -1.20 sensor
# V/V = -6.0 um/V and Fig. 14's -10 um at 1.65 V give the 3.0 scale).
STATIC_GAIN_SCALE_UM_PER_V = 3.0

# --- the controller design's defaults -----------------------------------------
# Defaults of nanosim.pipeline.config.DesignConfig, here because nanosim.design (the hinf-damped bench
# design, the damping loop) uses them too and may not import the pipeline.
# 14 states: the Hankel singular values of the identified models fall by more than an order of magnitude
# after the first twelve; states 13-14 keep the slowest creep stage, which raises the loop's gain below 1 Hz.
DEFAULT_REDUCED_ORDER = 14
# Damping ratio the inner active-damping loop adds to the first mode (0 = no damping loop).
DEFAULT_DAMPING_ZETA = 0.1
# Low-pass corner of the damping loop [Hz] (between the first and the second mode set).
DEFAULT_DAMPING_LOWPASS_HZ = 400.0

# --- the identification's default excitation ---------------------------------
# PRBS band edges [Hz], 1 s each: the paper's 50, 100 and 200 Hz, and a 1 kHz band (chip clock 2 kHz)
# that puts power at the stage's top mode below 1 kHz, the sixth (the table's twist; the paper's 740 Hz,
# from its Tustin-warped model). A PRBS held P samples has the spectrum sinc^2(f P / fs): with the paper's
# bands only, the 200 Hz band (P = 10, chip clock 400 Hz) puts that weakly observable mode some 16 dB
# under its low-frequency level, on the way to its 800 Hz null; the 1 kHz band (P = 2) under 2 dB
# (tests/test_identify_stage.py).
DEFAULT_PRBS_BANDS_HZ = (50.0, 100.0, 200.0, 1000.0)

# --- names -------------------------------------------------------------------
AXES = ("X", "Y", "Z")
ACTUATORS = ("A", "B", "C")

