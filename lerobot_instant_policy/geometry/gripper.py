"""The parallel gripper's keypoints in the EE frame (the graph's gripper nodes, docs/design.md §5)."""

# Metres; z is the approach axis, y the finger axis (the authors' code): the EE origin between the fingertips, 6 cm
# back along the approach axis, and ±6 cm along the finger axis at z = 0 and at z = 6 cm.
GRIPPER_KEYPOINTS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (0.0, 0.0, -0.06),
    (0.0, 0.06, 0.0),
    (0.0, -0.06, 0.0),
    (0.0, 0.06, 0.06),
    (0.0, -0.06, 0.06),
)
