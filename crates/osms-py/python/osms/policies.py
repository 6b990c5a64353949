"""The store's policies as Python callables.

``load("teacher")``, ``load("student_naive@0")``, ``load("scripted")``: each returns a
:class:`osms.NativePolicy`, a callable from a batch of observations (the dict that
:func:`osms.eval.evaluate` passes to a policy) to a ``(n, 24)`` float64 array of actions. It is
the same policy osms's own evaluation stages roll out: a teacher acts deterministically, a
student draws its noise from the protocol's stream for each condition.
"""

from osms._project import project as _project


def load(name, *, pipeline=None, store=None, profile=None, project=None):
    """The policy ``name``: ``scripted``, or a built instance of a ``teacher`` or ``student``
    stage (``teacher``, ``student_naive@0``, ``student_il#1``).

    Raises :class:`osms.OsmsError` naming what is missing (an unknown stage, an instance not
    built under the profile) and how to build it.
    """
    return _project(pipeline, store, profile, project).policy(name)
