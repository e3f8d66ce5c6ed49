"""eskin: recognise how a person touches a piezoelectric electronic skin.

The public API is re-exported here. Submodules are imported on first use, so that
``import eskin`` stays fast and a command that needs only the campaign reader does not
load the learning stack.

Data takes one road through the package:
simulator or recording -> campaign file -> preprocessing -> tensor kernel -> model selection
-> export -> C++ stream classifier -> serial link.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# public name -> submodule that defines it
_EXPORTS: dict[str, str] = {
    # tensor kernel (issue 2)
    "tensor_kernel": "kernel",
    "mode_distances": "kernel",
    "resolve_alphas": "kernel",
    "pattern_bases": "kernel",
    "PatternBases": "kernel",
    "bases_mode_distances": "kernel",
    "bases_tensor_kernel": "kernel",
    "kernel_from_distances": "kernel",
    # preprocessing (issue 3)
    "preprocess": "preprocess",
    "WindowConfig": "preprocess",
    "TouchDetector": "preprocess",
    "detect_windows": "preprocess",
    "subsample": "preprocess",
    # campaign format, importers, simulator (issue 3)
    "Campaign": "campaign",
    "CampaignFormatError": "campaign",
    "load_campaign": "campaign",
    "write_campaign": "campaign",
    "CampaignWriter": "campaign",
    "import_csv_folder": "importers",
    "import_tdms": "importers",
    "simulate": "simulator",
    "SimulatorConfig": "simulator",
    # learning and model selection (issue 4)
    "TensorSVC": "estimators",
    "TensorRLS": "estimators",
    "KernelKMeans": "estimators",
    "OneVsAllTouchClassifier": "estimators",
    "MaximalDiscrepancySearch": "selection",
    "CrossValidationSearch": "selection",
    "run_experiment": "experiments",
    "TouchModel": "models",
    "train_model": "models",
    "save_model": "models",
    "load_model": "models",
    # deployment (issue 5)
    "export_model": "export",
    "write_c_header": "export",
    "CompiledModel": "export",
    # serial link (issue 6)
    "FrameDecoder": "protocol",
    "encode_frame": "protocol",
    "LinkListener": "link",
    "SerialPort": "serial_port",
    "write_replay_file": "replay",
    "read_replay_file": "replay",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'eskin' has no attribute {name!r}")
    submodule = importlib.import_module(f"eskin.{module}")
    # a name that is also its submodule's name (eskin.preprocess) resolves to the submodule,
    # which is then callable, so that `import eskin.preprocess as m` keeps working
    value = submodule if name == module else getattr(submodule, name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
