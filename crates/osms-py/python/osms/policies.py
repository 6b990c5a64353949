"""The store's policies as Python callables.

``load("teacher")``, ``load("student_naive@0")``, ``load("scripted")``: each returns a
:class:`osms.NativePolicy`, a callable from a batch of observations (the dict that
:func:`osms.eval.evaluate` passes to a policy) to a ``(n, 24)`` float64 array of actions. It is
the same policy osms's own evaluation stages roll out: a teacher acts deterministically, a
student draws its noise from the protocol's stream for each condition, the scripted catcher
runs with the protocol stage's gains and inputs (``catcher``, ``prior_inputs``, …).

A loaded policy keeps per-rollout state (a teacher's phase, a student's noise stream) in the
pool it acts on, keyed by the load: two loads never share it. It answers each observation
once: a second call on the same batch raises :class:`osms.OsmsError` (it would advance a
student's noise and part from its stage's rows).
"""

from osms._project import project as _project


def load(name, *, pipeline=None, store=None, profile=None, project=None):
    """The policy ``name`` of the store, as an :class:`osms.NativePolicy` to pass to
    :func:`osms.eval.evaluate`: ``scripted``, or a built instance of a ``teacher`` or
    ``student`` stage (``teacher``, ``student_naive@0``, ``student_il#1``).

    ``pipeline``, ``store``, ``profile``, ``project``: which osms project (as for
    :func:`osms.eval.evaluate`).

    Raises :class:`osms.OsmsError` naming what is missing (an unknown name, with the valid
    ones; an instance not built under the profile, with the ``osms make`` that builds it).
    """
    return _project(pipeline, store, profile, project).policy(name)
