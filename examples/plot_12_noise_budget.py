"""
A noise budget you can read
===========================
Where a controller's positioning noise comes from, without a simulation: each noise source's spectrum (DAC,
amplifier, gauge, floor vibration, the two quantizers as white noise) through the closed-loop transfer
functions of the loop as the bench runs it on the linear twin (Fleming, "Measuring and predicting
resolution in nanopositioning systems", Mechatronics 24 (2014) 605). Three bench members designed on the
same identified model: the default ``hinf``, the paper's design and integral resonant control (``irc``).
The cumulative amplitude spectrum's top is each controller's sigma; its steps show the frequencies that make
it. ``nanosim budget --controller runs/demo/controller.npz --out runs/budget`` writes the same for any
controller file, and ``--simulate S`` checks it against closed-loop simulations of S seconds.
"""
import matplotlib.pyplot as plt

from nanosim import IdentifySettings, Stage, identify_on_twin
from nanosim.design.architectures import design
from nanosim.experiments.noise_budget import analytic_budget, cumulative_amplitude, loop_model
from nanosim.plots.budget import figure_budget_cas, figure_budget_psd

ident, _ = identify_on_twin(settings=IdentifySettings(seed=0))
lm = loop_model(Stage())                       # the twin's loop: mechanics, piezo small-signal gain, filters
budgets = {}
for name in ("hinf", "paper", "irc"):
    d = design(name, ident.sysd)
    budgets[name] = b = analytic_budget(d.config, lm, axis=0)
    top = sorted(((v, k) for k, v in b.sigma_table_nm.items() if k != "total"), reverse=True)[:2]
    print(f"{name:>6}: X table sigma {b.sigma_table_nm['total']:.2f} nm; largest sources "
          + ", ".join(f"{k} {v:.2f} nm" for v, k in top))

# %%
# The default controller's budget as ``nanosim budget`` draws it: the stacked PSD per source of the table's
# X position, and each source's cumulative amplitude spectrum.
b = budgets["hinf"]
fig_psd = figure_budget_psd(b.freq_hz, b.psd_table_nm2_hz, "hinf: stacked PSD per source, X table position")
fig_cas = figure_budget_cas(b.freq_hz, b.psd_table_nm2_hz, b.sigma_table_nm, "hinf: cumulative amplitude spectrum")

# %%
# The three controllers' totals side by side. The paper's design leaves the first mode pair near its open-loop
# damping: its curve climbs at 174-177 Hz, where the floor's vibration and the quantizers' broadband input ring
# the pair; the default and IRC damp it, and their steps there are a fraction of the paper's.
fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
for name, b in budgets.items():
    total = sum(b.psd_table_nm2_hz.values())
    ax.semilogx(b.freq_hz, cumulative_amplitude(b.freq_hz, total), label=f"{name}: {b.sigma_table_nm['total']:.2f} nm")
ax.set_xlabel("frequency [Hz]")
ax.set_ylabel("cumulative amplitude [nm rms]")
ax.set_title("X table position, cumulative amplitude spectrum")
ax.legend()
