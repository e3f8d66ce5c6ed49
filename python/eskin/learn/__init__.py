"""The learning layer: the tensor kernel, the tensor machines, model selection (maximal
discrepancy, cross-validation) and the touch model's recipe (train, save, load). Builds on
eskin.data and eskin.signal.
"""

from .estimators import (
    KernelKMeans,
    OneVsAllTouchClassifier,
    TensorRLS,
    TensorSVC,
    TouchDecision,
    kernel_kmeans,
)
from .kernel import (
    PatternBases,
    bases_mode_distances,
    bases_tensor_kernel,
    kernel_from_distances,
    mode_distances,
    pattern_bases,
    pattern_log_energy,
    resolve_alphas,
    tensor_kernel,
)
from eskin.errors import ModelFormatError, TrainingError
from .models import TouchModel, error_rate, load_model, register_model_format, save_model
from .training import train_model
from .training_set import ArrayRecordings, Prepared, preprocess_campaign
from .selection import (
    MD_READINGS,
    PAPER_GRID,
    CrossValidationSearch,
    MaximalDiscrepancySearch,
    md_reading,
    md_tau,
    rls_eig_solve,
)

__all__ = [
    "MD_READINGS",
    "PAPER_GRID",
    "ArrayRecordings",
    "CrossValidationSearch",
    "KernelKMeans",
    "MaximalDiscrepancySearch",
    "ModelFormatError",
    "OneVsAllTouchClassifier",
    "PatternBases",
    "Prepared",
    "TensorRLS",
    "TensorSVC",
    "TouchDecision",
    "TouchModel",
    "TrainingError",
    "bases_mode_distances",
    "bases_tensor_kernel",
    "error_rate",
    "kernel_from_distances",
    "kernel_kmeans",
    "load_model",
    "md_reading",
    "md_tau",
    "mode_distances",
    "pattern_bases",
    "pattern_log_energy",
    "preprocess_campaign",
    "register_model_format",
    "resolve_alphas",
    "rls_eig_solve",
    "save_model",
    "tensor_kernel",
    "train_model",
]
