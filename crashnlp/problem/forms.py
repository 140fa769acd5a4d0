"""The registry of model forms: `model.form` -> the class that builds it.

A form is one module holding a `crashnlp.models.form.CrashModel` subclass; registering it is one
entry here. The entries name the class by import path, so the problem schema can take its
`model.form` choice from this registry without importing CasADi;
`crashnlp.models.form.form_class` imports it.
"""

from __future__ import annotations

FORMS: dict[str, str] = {
    "pendulum": "crashnlp.models.pendulum:PendulumModel",  # the paper: pitches about the impact point
    "rigid-body": "crashnlp.models.rigid_body:RigidBodyModel",  # pitches about its CG on the suspension
    # the rigid body with an engine on mounts that meets the barrier late
    "engine-on-mounts": "crashnlp.models.engine_on_mounts:EngineOnMountsModel",
}
DEFAULT_FORM = "pendulum"
# The forms `crashnlp compare` fits: those with a calibration table of their own
# (crashnlp/analysis/calibration.json) whose choice holds on vehicles of every generator form.
# engine-on-mounts has a table, but among these it was chosen on vans without an engine, whose
# rigid body scored several times better (the forms benchmark, CHANGELOG.md): it is chosen by naming it.
COMPARED: tuple[str, ...] = ("pendulum", "rigid-body")
