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
# The forms `crashnlp compare` fits unless told (`--forms`), with the problem's own model.form.
# engine-on-mounts is fitted when named (there or in --forms):
# its fits cost many times the others' (docs/design-notes.md, "Which form: the score, not the lift-off").
COMPARED: tuple[str, ...] = ("pendulum", "rigid-body")
# The vehicle entries only some forms read, each with a form that reads it: a problem of another
# form that gives one is refused (crashnlp.case.case.Case.refuse_unread_given).
READ_BY: dict[str, str] = {"engine": "engine-on-mounts", "crush_offset": "pendulum"}
