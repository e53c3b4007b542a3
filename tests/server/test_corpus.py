"""The whole ../shared/gltf-corpus through the real upload endpoint: valid models ingest or get a
named "unsupported" 4xx, invalid ones get a 4xx, missing textures are named, nothing gets a 500."""
from __future__ import annotations

import io
import json
import zipfile
from collections import Counter
from pathlib import Path

from tests.conftest import shared_path


def _zip_model(gltf: Path) -> bytes:
    """The .gltf and every resource file of its folder (textures in sub-folders too) as one zip."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.write(gltf, gltf.name)
        for p in gltf.parent.rglob("*"):
            if p.is_file() and p.suffix.lower() not in (".gltf", ".md", ".json"):
                z.write(p, p.relative_to(gltf.parent).as_posix())
    return buf.getvalue()


def test_corpus_through_the_api(running):
    root = shared_path("gltf-corpus")
    entries = json.loads((root / "MANIFEST.json").read_text())
    outcomes = Counter()
    problems = []
    for e in entries:
        path = root / e["file"]
        r = running.client.post("/v1/scenes", content=_zip_model(path), headers={"X-Filename": path.stem + ".zip"})
        if r.status_code >= 500:
            problems.append(f"{e['file']}: {r.status_code} {r.text}")
            continue
        body = r.json()
        missing_tex = "missing-texture" in e["file"]
        if r.status_code in (200, 201):
            outcomes["ingested"] += 1
            if missing_tex:
                problems.append(f"{e['file']}: ingested although its texture is missing")
            elif e["expected"] == "invalid" and e["category"].endswith("negative"):
                problems.append(f"{e['file']}: an invalid model was accepted")
            else:
                assert body["triangles"] > 0
            continue
        code = body["error"]["code"]
        outcomes[f"{r.status_code} {code}"] += 1
        assert 400 <= r.status_code < 500 and body["error"]["message"]
        if missing_tex:
            if code != "missing_resource" or ".png" not in body["error"]["message"]:
                problems.append(f"{e['file']}: missing texture reported as {code}: {body['error']['message']}")
        elif e["expected"] == "valid" and code not in ("unsupported", "unsupported_extension"):
            problems.append(f"{e['file']}: a valid model was refused with {code}: {body['error']['message']}")
    print(dict(outcomes))
    assert not problems, "\n".join(problems)
    assert outcomes["ingested"] >= 150
