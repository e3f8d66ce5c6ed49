"""The deployment layer: the ``.eskin`` model file and the C header for the controller, and
the compiled model (the C++ stream classifier) that runs them, and the controller targets a model
must fit (flash and RAM, :mod:`eskin.deploy.target`), and the engine that runs many patches of a
skin on one host (:mod:`eskin.deploy.skin_engine`). Builds on eskin.learn.

Importing this package registers the ``.eskin`` suffix with the model files of
:mod:`eskin.learn.models`, so that :func:`save_model` / :func:`load_model` (re-exported here)
read and write both the joblib container and the ``.eskin`` file.
"""

from eskin.learn.models import load_model, save_model

from .export import (
    FORMAT_VERSION,
    FORMAT_VERSIONS,
    MAGIC,
    CompiledDecisions,
    CompiledModel,
    MachineSpec,
    ModelFormatError,
    ModelSpec,
    compiled_engine,
    export_model,
    format_version,
    model_to_bytes,
    spec_from_estimator,
    spec_from_model,
    write_c_header,
)
from .skin_engine import SkinDecision, SkinEngine
from .target import TARGETS, DeviceBudget, Target, device_budget

__all__ = [
    "FORMAT_VERSION",
    "FORMAT_VERSIONS",
    "MAGIC",
    "TARGETS",
    "CompiledDecisions",
    "CompiledModel",
    "DeviceBudget",
    "MachineSpec",
    "ModelFormatError",
    "ModelSpec",
    "SkinDecision",
    "SkinEngine",
    "Target",
    "compiled_engine",
    "device_budget",
    "export_model",
    "format_version",
    "load_model",
    "model_to_bytes",
    "save_model",
    "spec_from_estimator",
    "spec_from_model",
    "write_c_header",
]
