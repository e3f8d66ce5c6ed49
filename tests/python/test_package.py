import subprocess
import sys

import eskin


def test_public_names_resolve_lazily():
    assert "tensor_kernel" in dir(eskin)
    assert eskin.__version__.count(".") == 2


def test_unknown_attribute_is_an_error():
    import pytest

    with pytest.raises(AttributeError, match="no_such_thing"):
        eskin.no_such_thing  # noqa: B018


def test_cli_version_runs():
    out = subprocess.run(
        [sys.executable, "-m", "eskin", "version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == eskin.__version__
