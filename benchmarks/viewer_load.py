"""Time how long the viewer's three.js takes to load a coverage.glb in headless Chromium.

Usage: python benchmarks/viewer_load.py FILE.glb [FILE.glb ...] [--repeat K]

Serves the files and the vendored three.js (service/static/vendor) from a local HTTP server,
loads each file with three's GLTFLoader and meshopt decoder (as service/static/viewer.js
does) and draws one frame with SwiftShader (software WebGL, as in tests/e2e/test_viewer.py).
Prints, per file, its size, the load time (fetch + parse + decode) and the time to the
first drawn frame, best of K. Localhost transfer is nearly free: over a network, add the
file size divided by the bandwidth. Make a glb with e.g. ``scanplan plan
../shared/scenes/AC20-FZK-Haus.ifc --out DIR`` (1.16 M faces at the default max_edge_m).
"""

from __future__ import annotations

import argparse
import functools
import http.server
import shutil
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

from playwright.sync_api import sync_playwright

VENDOR = Path(__file__).resolve().parents[1] / "service" / "static" / "vendor"
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader"]
PAGE = """<!doctype html><html><body><canvas id="c" width="800" height="600"></canvas>
<script type="importmap">{"imports": {"three": "./vendor/three/three.module.js",
  "three/addons/": "./vendor/three/addons/"}}</script>
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';
const t0 = performance.now();
const loader = new GLTFLoader();
loader.setMeshoptDecoder(MeshoptDecoder);
try {
  const gltf = await loader.loadAsync(new URLSearchParams(location.search).get('f'));
  const loaded = performance.now();
  const renderer = new THREE.WebGLRenderer({ canvas: document.getElementById('c') });
  const scene = new THREE.Scene();
  scene.add(gltf.scene, new THREE.HemisphereLight(0xffffff, 0x888888, 2));
  const box = new THREE.Box3().setFromObject(gltf.scene);
  const centre = box.getCenter(new THREE.Vector3());
  const span = box.getSize(new THREE.Vector3()).length();
  const camera = new THREE.PerspectiveCamera(45, 4 / 3, span / 500, span * 10);
  camera.position.copy(centre).add(new THREE.Vector3(span, span, span));
  camera.lookAt(centre);
  renderer.render(scene, camera);
  renderer.getContext().finish();
  let triangles = 0;
  gltf.scene.traverse((o) => {
    if (o.isMesh) triangles += o.geometry.attributes.position.count / 3;
  });
  window.result = { load_ms: loaded - t0, frame_ms: performance.now() - t0, triangles };
} catch (err) {
  window.result = { error: String(err) };
}
</script></body></html>
"""


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "index.html").write_text(PAGE)
        (root / "vendor").symlink_to(VENDOR)
        for k, path in enumerate(args.files):
            shutil.copyfile(path, root / f"{k}.glb")
        server = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), functools.partial(_QuietHandler, directory=str(root)))
        threading.Thread(target=server.serve_forever, daemon=True).start()
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            for k, path in enumerate(args.files):
                runs = []
                for _ in range(args.repeat):
                    page = browser.new_page()
                    page.goto(f"http://127.0.0.1:{server.server_port}/index.html?f={k}.glb")
                    page.wait_for_function("window.result !== undefined", timeout=600_000)
                    result = page.evaluate("window.result")
                    page.close()
                    if "error" in result:
                        raise SystemExit(f"{path}: {result['error']}")
                    runs.append(result)
                print(f"{path}: {path.stat().st_size / 1e6:.1f} MB, "
                      f"{runs[0]['triangles']:,} triangles, best of {len(runs)}: loaded in "
                      f"{min(r['load_ms'] for r in runs) / 1000:.2f} s, first frame at "
                      f"{min(r['frame_ms'] for r in runs) / 1000:.2f} s")
            browser.close()
        server.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
