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
           "PIEZO_FORCE_PER_PIEZO_V", "SENSOR_UM_PER_V", "SENSOR_RANGE_UM", "SENSOR_NOISE_NM_RMS_1KHZ",
           "ADC_BITS", "ADC_FULL_SCALE_V", "ADC_LSB_V", "ADC_LSB_NM", "JACOBIAN_J",
           "STATIC_GAIN_SCALE_UM_PER_V", "AXES", "ACTUATORS"]

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

# --- names -------------------------------------------------------------------
AXES = ("X", "Y", "Z")
ACTUATORS = ("A", "B", "C")

