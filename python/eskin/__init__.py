"""eskin: recognise how a person touches a piezoelectric electronic skin.

The public API is re-exported here. The package's folders are its layers, each importing only
the ones below it: data -> signal -> learn -> deploy -> link -> experiments -> cli (see
docs/architecture.md). The layers are imported on first use, so that ``import eskin`` stays
fast and a command that needs only the campaign reader does not load the learning stack.

Data takes one road through the package:
simulator or recording -> campaign file -> preprocessing -> tensor kernel -> model selection
-> export -> C++ stream classifier -> serial link.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# public name -> the layer (subpackage) that exports it
_EXPORTS: dict[str, str] = {
    # tensor kernel
    "tensor_kernel": "learn",
    "mode_distances": "learn",
    "resolve_alphas": "learn",
    "pattern_bases": "learn",
    "pattern_log_energy": "learn",
    "PatternBases": "learn",
    "bases_mode_distances": "learn",
    "bases_tensor_kernel": "learn",
    "kernel_from_distances": "learn",
    # preprocessing
    "preprocess": "signal",
    "WindowConfig": "signal",
    "TouchDetector": "signal",
    "detect_windows": "signal",
    "subsample": "signal",
    # campaign format, importers, simulator
    "Campaign": "data",
    "load_campaign": "data",
    "write_campaign": "data",
    "CampaignWriter": "data",
    "recover_campaign": "data",
    "import_csv_folder": "data",
    "import_tdms": "data",
    "simulate": "data",
    "SimulatorConfig": "data",
    "Skin": "data",
    "load_skin": "data",
    "simulate_skin": "data",
    # learning and model selection
    "TensorSVC": "learn",
    "TensorRLS": "learn",
    "KernelKMeans": "learn",
    "OneVsAllTouchClassifier": "learn",
    "MaximalDiscrepancySearch": "learn",
    "CrossValidationSearch": "learn",
    "run_experiment": "experiments",
    "TouchModel": "learn",
    "train_model": "learn",
    "save_model": "deploy",  # through eskin.deploy, which adds the .eskin format
    "load_model": "deploy",
    # deployment
    "export_model": "deploy",
    "write_c_header": "deploy",
    "CompiledModel": "deploy",
    "SkinEngine": "deploy",
    "SkinDecision": "deploy",
    # serial link
    "FrameDecoder": "link",
    "encode_frame": "link",
    "LinkListener": "link",
    "SkinListener": "link",
    "SerialPort": "link",
    # error types (one home each: eskin.errors)
    "CampaignFormatError": "errors",
    "SkinFormatError": "errors",
    "ReplayFormatError": "errors",
    "ModelFormatError": "errors",
    "TrainingError": "errors",
    "ExperimentError": "errors",
    "SerialPortError": "errors",
    "OverwriteError": "errors",
    "write_replay_file": "data",
    "read_replay_file": "data",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str) -> Any:
    layer = _EXPORTS.get(name)
    if layer is None:
        raise AttributeError(f"module 'eskin' has no attribute {name!r}")
    # eskin.preprocess is the callable module eskin.signal.preprocess (so that
    # `import eskin.signal.preprocess as m` and `eskin.preprocess(x)` are the same object)
    value = getattr(importlib.import_module(f"eskin.{layer}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
