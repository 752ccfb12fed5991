"""The map service loads its policy's fusion kernel while it starts, not on the first scan."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("policy", ["binary", "dual"])
def test_a_started_map_service_has_its_policys_fusion_kernel_and_no_other(tmp_path, policy):
    # a fresh interpreter: in this one another test may have loaded every kernel already
    script = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(ROOT / "tests")!r})
        from mapserver.core import fusion_kernel as kernel
        from mapserver.core.sensor_model import POLICY_CODES, Policy
        from server_helpers import small_settings
        from mapserver.service.map_service import MapService
        service = MapService(small_settings({str(tmp_path / "data")!r}, policy={policy!r}))
        loaded = sorted(code for code, k in kernel.POLICY_FUSE_BATCH.items() if k.signatures)
        print(loaded == [POLICY_CODES[Policy({policy!r})]], service.kernel_load_seconds >= 0)
        service.close()
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "True"]
