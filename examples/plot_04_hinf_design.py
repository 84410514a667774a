"""
H-infinity design with the paper's weights
==========================================

The paper's procedure (Sec. 4): balanced truncation of the identified model to 10 states with its DC
gain matched, mixed-sensitivity H-infinity synthesis with the weights ``Wp``, ``Wu``, ``Wt`` of the paper,
and the 4 kHz discretization. The model is identified on the linear twin, as in the identification example.
``nanosim design --paper-design`` does the same on a run's ``model.npz``.
"""
from nanosim import IdentifySettings, design_hinf, discretize_controller, identify_on_twin, reduce_model
from nanosim.design import paper_weights
from nanosim.paper import PAPER_CONTROLLER_ORDER, PAPER_GAMMA
from nanosim.plots.design import plot_hankel, plot_sensitivity, plot_weights

ident, twin = identify_on_twin(settings=IdentifySettings(seed=0))      # the bundled stage, on its linear twin

# %%
# Balanced truncation: the Hankel singular values say how many states carry the response.
red = reduce_model(ident.sysc, order=10)
print(f"{red.full_order} -> {red.order} states, DC gain error {red.dc_gain_rel_error:.1e}")
hankel = plot_hankel(red)

# %%
# The paper's weights and the synthesis.
W = paper_weights()
weights_figure = plot_weights(W)
d = design_hinf(red.G_reduced, W, G_full=ident.sysc, G_twin=twin.sys_V)
print(f"gamma {d.gamma:.3f} (paper {PAPER_GAMMA}), controller order {d.controller_order} "
      f"(paper {PAPER_CONTROLLER_ORDER})")
print(f"S bandwidth {d.nominal.bandwidth_S_hz:.1f} Hz, least closed-loop damping {d.nominal.min_damping:.4f} "
      f"at {d.nominal.min_damping_hz:.0f} Hz")
sensitivity = plot_sensitivity(d)

# %%
# The loop runs at 4 kHz: the controller is discretized and its frequency response checked to 500 Hz.
disc = discretize_controller(d.K)
print(f"discretized by {disc.method}: max relative error {disc.max_rel_error:.2%} below {disc.f_check_hz:.0f} Hz")
