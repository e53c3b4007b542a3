"""persist/export.py: a bake's bundle folder from the store."""
from __future__ import annotations

import numpy as np

from persist.export import export_bundle
from persist.store import Store
from proto import bundle
from proto.models import Manifest, SceneSummary


def test_export_bundle_writes_the_artifacts_and_the_manifest(tmp_path):
    s = Store(tmp_path / "store")
    src = tmp_path / "src"
    info = bundle.write_artifact(src, "probe_sh", np.arange(24, dtype=np.float32).reshape(2, 2, 2, 3), "light",
                                 format="npy")
    s.put_file(src / info.file)
    m = Manifest(kiln_version="0", bake_id="b", scene=SceneSummary(id="ab" * 32, triangles=1, bounds=[], lights=0,
                                                                   materials=0),
                 config={}, grid={}, stages=[], artifacts=[info])
    out = export_bundle(s, m, tmp_path / "out")
    assert out == tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", info.file]
    assert (out / info.file).read_bytes() == (src / info.file).read_bytes()
    manifest, arrays = bundle.open_bundle(out)            # sizes and hashes checked
    assert manifest == m and np.array_equal(arrays["probe_sh"], np.arange(24, dtype=np.float32).reshape(2, 2, 2, 3))
