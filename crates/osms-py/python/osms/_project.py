"""The project every entry point reads: one per (pipeline, store, profile), opened once."""

import os

from osms._native import Project

_open = {}


def project(pipeline=None, store=None, profile=None, project=None):
    """``project`` if given, else the (cached) project of ``pipeline``, ``store`` and ``profile``.

    ``OSMS_PIPELINE``, ``OSMS_STORE`` and ``OSMS_PROFILE`` stand in for arguments not given.
    """
    if project is not None:
        return project
    pipeline = pipeline or os.environ.get("OSMS_PIPELINE")
    store = store or os.environ.get("OSMS_STORE")
    profile = profile or os.environ.get("OSMS_PROFILE")
    key = (
        os.path.abspath(pipeline) if pipeline else os.getcwd(),
        os.path.abspath(store) if store else None,
        profile,
    )
    if key not in _open:
        _open[key] = Project(pipeline, store, profile)
    return _open[key]


def protocol(proj, conditions="dev", protocol=None):
    """The protocol named, else osms's default one for the condition set ``conditions``."""
    return proj.protocol(protocol or proj.default_protocol(conditions))
