"""Demonstrations replayed in the live scene: ``plan`` (a demonstration registered onto the live cloud whole, per
object or per anchored segment, or by the demonstrations' consensus, and its actions moved there), ``agreement`` (how
far the demonstrations' own plans part in the live scene), ``segments`` (a demonstration's actions cut at gripper
changes, stops and turns, each segment anchored to what it approaches; when a plan is wrong), ``timing`` (the one
timing model: the plan step a live episode has reached at each frame, the steps a prior reads) and ``priors`` (the
planned actions the ``instant_policy`` inference, its training stream and its offline validation start from). It
builds on ``contract``, ``geometry`` and ``data``, and nothing below it imports it."""
