"""
Identification of the stage
===========================

The paper's identification, run on the linear twin of the stage in the full electromechanics (DAC, amplifier,
piezo hysteresis and creep, gauge, ADC; the same runner ``nanosim sweep`` uses for its points): a step and
multi-band PRBS per actuator, a 3x1 subspace model (PO-MOESP) per column, the shared resonances re-estimated
jointly from the three records, then the validation fit of every channel. ``nanosim identify`` runs the same
experiments on the MuJoCo stage.
"""
import numpy as np

from nanosim import IdentifySettings, identify_on_twin
from nanosim.paper import PAPER_FIT_PERCENT
from nanosim.plots.identify import figure_bode_grid

ident, twin = identify_on_twin(settings=IdentifySettings(seed=0))      # the bundled stage, on its linear twin
print("identified model:", ident.sysd.nstates, "states")
poles = ident.sysc.poles()
light = poles[(poles.imag > 0) & (-poles.real < 0.05 * np.abs(poles))]
print("lightly damped poles [Hz]:", np.round(np.sort(np.abs(light)) / (2 * np.pi), 1))
print("validation fit [%], rows X Y Z, columns A B C:")
print(np.round(ident.fit_percent, 1))
print("the paper's Table 1:")
print(PAPER_FIT_PERCENT)

# %%
# The identified model against the twin it was identified from.
bode = figure_bode_grid([ident.sysd, twin.sysd_V], ["identified", "linear twin"],
                        "Identified 3x3 model vs the linear twin", fmin=5.0, fmax=1500.0,
                        styles=[{}, {"ls": "--", "lw": 1}])
