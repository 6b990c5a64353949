"""osms from Python: the catching world of *Outcome-Sensitive Motion Search* as a gymnasium
environment (``osms/Catch-v0``), bit-exact batch evaluation of any policy on osms's condition
sets (:func:`osms.eval.evaluate`) and the store's teacher, students and scripted catcher as
callables (:func:`osms.policies.load`). ``osms.CatchEnv`` and ``osms.CatchVectorEnv`` are the
environment's classes (``osms.gym``'s; they import gymnasium on first use).

Everything reads an osms project: its ``pipeline.toml`` (found from the working directory, or
passed as ``pipeline=``), a profile and the store beside it that ``osms make`` built. A store
that does not exist yet is created; the package writes into it only the world and condition
sets a protocol needs (built on first use), never another artifact.
"""

from osms._native import (
    DEFAULT_CONTROL_HZ,
    DEFAULT_MAX_STEPS,
    DEPLOYABLE_LEN,
    N_ACTION,
    PRIVILEGED_LEN,
    ActionError,
    NativePolicy,
    OsmsError,
    Project,
    Protocol,
    __version__,
    channels,
    row_columns,
)

from osms import eval, policies  # noqa: E402,A004  (submodules need the names above)

# `eval` stays out: `from osms import *` must not replace the builtin `eval`.
__all__ = [
    "DEFAULT_CONTROL_HZ",
    "DEFAULT_MAX_STEPS",
    "DEPLOYABLE_LEN",
    "N_ACTION",
    "PRIVILEGED_LEN",
    "ActionError",
    "NativePolicy",
    "OsmsError",
    "Project",
    "Protocol",
    "__version__",
    "channels",
    "policies",
    "row_columns",
]



def __getattr__(name):
    # The environments need gymnasium, which evaluation does not: imported on first use.
    if name in ("CatchEnv", "CatchVectorEnv"):
        import osms.gym

        return getattr(osms.gym, name)
    raise AttributeError(f"module 'osms' has no attribute {name!r}")


try:
    import gymnasium as _gymnasium
except ImportError:  # the environment needs gymnasium; evaluation does not
    pass
else:
    if "osms/Catch-v0" not in _gymnasium.registry:
        # The world ends every episode of the default protocol within DEFAULT_MAX_STEPS
        # control steps; the limit is registered for evaluators that read it (LeRobot's
        # `env.call("_max_episode_steps")`).
        _gymnasium.register(
            id="osms/Catch-v0",
            entry_point="osms.gym:CatchEnv",
            vector_entry_point="osms.gym:CatchVectorEnv",
            max_episode_steps=DEFAULT_MAX_STEPS,
        )
