"""The viewer's labels do not overlap on the first view, and its physics text states its decision and fits."""






# --- the viewer: labels and the physics panel ---------------------------------------------------------
def test_viewer_labels_do_not_overlap_on_the_first_view(model):
    """Labels such as "probe Z" and "table + target cube" do not overlap."""
    from nanosim.plant.mechanics import home_data
    from nanosim.viewer.labels import LABEL_TEXTS, box_gap, label_boxes, label_positions

    anchors = label_positions(model, home_data(model))
    texts = dict(LABEL_TEXTS, **{k: "piezo A" for k in anchors if k not in LABEL_TEXTS})
    boxes = label_boxes(anchors, texts)
    names = sorted(boxes)
    gaps = {(a, b): box_gap(boxes[a], boxes[b]) for i, a in enumerate(names) for b in names[i + 1:]}
    assert min(gaps.values()) > 0.5, min(gaps.items(), key=lambda kv: kv[1])
    assert gaps[("probe_z", "table")] >= 3.0


def test_viewer_auto_physics_text_shows_its_decision_and_fits():
    """The physics choice states the real-time factor it was made on, and fits the panel."""
    from nanosim.viewer.server import AUTO_WINDOW_S, PHYSICS_TEXT_MAX, physics_text

    for physics, rtf in (("mujoco", 0.9612), ("linear", 0.2134), ("linear", 0.0049), ("mujoco", 3.5)):
        text = physics_text(physics, rtf)
        assert f"{rtf:.2f}x" in text and f"{AUTO_WINDOW_S:g} s" in text and len(text) <= PHYSICS_TEXT_MAX, text
        assert ("MuJoCo (" if physics == "mujoco" else "linearized") in text
    assert len(physics_text("mujoco")) <= PHYSICS_TEXT_MAX
