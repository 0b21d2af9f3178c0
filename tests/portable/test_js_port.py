"""The JavaScript port (runtime/web/mogo.mjs, onnxruntime-web's WebAssembly backend) against
the conformance vectors: under Node here, in headless Chromium in test_browser.py."""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

import mogo

WEB = Path(mogo.__file__).parent / "web"
NODE = shutil.which("node")


@pytest.mark.skipif(NODE is None, reason="needs Node.js 18+ (apt-get install -y nodejs)")
def test_the_port_passes_the_conformance_vectors_under_node(portable_bundle):
    result = subprocess.run(
        [NODE, str(WEB / "check.mjs"), str(portable_bundle)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-2000:] + result.stdout[-2000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["problems"] == []
    vectors = json.loads((WEB / "conformance.json").read_text())
    assert [c["name"] for c in report["cases"]] == [c["name"] for c in vectors["generate"]]
    for case in report["cases"]:  # on this machine no near tie is met: every step agrees
        assert case["agreed"] == case["steps"], case


@pytest.mark.skipif(NODE is None, reason="needs Node.js 18+ (apt-get install -y nodejs)")
def test_the_node_check_fails_on_a_wrong_vector(portable_bundle, tmp_path):
    vectors = json.loads((WEB / "conformance.json").read_text())
    vectors["random"] = vectors["random"][:1]
    vectors["random"][0]["uniforms"][3] += 1e-9
    vectors["generate"] = []
    (tmp_path / "wrong.json").write_text(json.dumps(vectors))
    result = subprocess.run(
        [NODE, str(WEB / "check.mjs"), str(portable_bundle), str(tmp_path / "wrong.json")],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 1
    assert json.loads(result.stdout.strip().splitlines()[-1])["problems"][0].startswith(
        "random seed 0 draw 3"
    )
