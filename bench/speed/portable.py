"""`python -m mogo.bench.speed.portable`: the portable bundle (`mogo export portable`) measured
for docs/portable.md, as markdown: its size, every graph's opset and ops, token agreement with
the int8 bundle, and how fast a 5-s clip comes out of it in our runtime, in the JavaScript port
under Node and in headless Chromium (those two skipped where absent).

Also the static file server and the headless Chromium that tests/portable uses: one page
server, no mogo process."""

from __future__ import annotations

import collections
import contextlib
import functools
import http.server
import json
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import onnx

import mogo
from mogo import MotionGenerator, Sampling
from mogo.bench.speed.timing import interleaved, log
from mogo.generator import DEFAULT_BUNDLE
from mogo.motion.skeleton import SMPL_22

WEB = Path(mogo.__file__).parent / "web"
CHROMIUM = "/usr/bin/chromium"
PROMPT, SECONDS, SEED = "a person walks forward", 5.0, 0
AGREEMENT_PROMPTS = (
    "a person walks forward",
    "a person jumps",
    "a person waves",
    "a person jogs in a circle",
    "a person sits down",
)
AGREEMENT_STEPS = 30


class _QuietFiles(http.server.SimpleHTTPRequestHandler):
    extensions_map = {
        **http.server.SimpleHTTPRequestHandler.extensions_map,
        ".mjs": "text/javascript",
        ".wasm": "application/wasm",
    }

    def log_message(self, *args):
        pass


@contextlib.contextmanager
def page_site(bundle: Path) -> Iterator[str]:
    """http://127.0.0.1:PORT with /web/ (the package's web folder) and /bundle/ (`bundle`),
    served by a thread of this process: files only. (From file:// Chromium blocks the page's
    module scripts: an origin of null.)"""
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        (root / "web").symlink_to(WEB)
        (root / "bundle").symlink_to(Path(bundle).resolve())
        server = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), functools.partial(_QuietFiles, directory=str(root))
        )
        threading.Thread(target=server.serve_forever, daemon=True).start()
        try:
            yield f"http://127.0.0.1:{server.server_address[1]}"
        finally:
            server.shutdown()
            server.server_close()


def chromium_driver() -> str | None:
    """chromedriver's path where Chromium and it are installed, else None."""
    driver = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    return driver if Path(CHROMIUM).exists() and Path(driver).exists() else None


@contextlib.contextmanager
def headless_chromium(window: str = "960,720"):
    from selenium import webdriver

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    with tempfile.TemporaryDirectory() as profile:
        for flag in (
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--window-size={window}",
            f"--user-data-dir={profile}",
        ):
            options.add_argument(flag)
        browser = webdriver.Chrome(
            options=options, service=webdriver.ChromeService(executable_path=chromium_driver())
        )
        browser.set_page_load_timeout(60)
        try:
            yield browser
        finally:
            browser.quit()


def wait_for(browser, name: str, seconds: float = 300):
    """window[name] once the page has set it; AssertionError with the page's error."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        error = browser.execute_script("return window.mogoError || null")
        assert error is None, error
        value = browser.execute_script(f"return window.{name} || null")
        if value is not None:
            return value
        time.sleep(0.5)
    raise AssertionError(f"no window.{name} within {seconds} s")


def page_url(site: str, **query: object) -> str:
    from urllib.parse import urlencode

    return f"{site}/web/index.html?" + urlencode(dict(bundle="../bundle/", **query))


def main() -> None:
    from mogo.export.onnx.portable import export_portable

    with tempfile.TemporaryDirectory() as folder:
        bundles = {"int8 (shipped)": DEFAULT_BUNDLE}
        for name, fp16 in (("portable fp16", True), ("portable fp32", False)):
            log(f"exporting the {name} bundle")
            bundles[name] = Path(folder) / name.replace(" ", "_")
            export_portable(DEFAULT_BUNDLE, bundles[name], fp16=fp16)
        portable = bundles["portable fp16"]
        print(_sizes(bundles))
        print(_ops(portable))
        generators = {name: MotionGenerator.load(path) for name, path in bundles.items()}
        print(_agreement(generators["int8 (shipped)"], generators["portable fp16"]))
        print(_runtime_speed(generators))
        if shutil.which("node"):
            print(_node(portable, generators["portable fp16"]))
        if chromium_driver():
            print(_browser(portable))


def _sizes(bundles: dict[str, Path]) -> str:
    rows = ["| bundle | files | MB |", "|---|---|---|"]
    for name, path in bundles.items():
        manifest = MotionGenerator.load(path).manifest
        rows.append(f"| {name} | {len(manifest.files)} | {manifest.total_bytes / 1e6:.1f} |")
    manifest = MotionGenerator.load(bundles["portable fp16"]).manifest
    page = [g.file for g in manifest.t2m.levels] + [
        manifest.vq.decoder.file,
        manifest.text.trained.encoder.file,
        manifest.text.trained.tokenizer,
        "mean.npy",
        "std.npy",
        "manifest.json",
    ]
    page_bytes = sum((bundles["portable fp16"] / f).stat().st_size for f in page)
    vendor = {p.name: p.stat().st_size for p in sorted((WEB / "vendor").iterdir())}
    return "\n".join(rows) + (
        f"\n\nThe page fetches {len(page)} files of the portable fp16 bundle, "
        f"{page_bytes / 1e6:.1f} MB (the level graphs, the decoder, the trained text "
        "encoder and its tokenizer, mean, std, manifest), and the vendored scripts: "
        + ", ".join(
            f"{name} {size / 1e6:.2f} MB"
            for name, size in vendor.items()
            if not name.startswith("LICENSE")
        )
        + ".\n"
    )


def _ops(bundle: Path) -> str:
    manifest = MotionGenerator.load(bundle).manifest
    rows = ["| graph | opset | ops (count) |", "|---|---|---|"]
    union: set[str] = set()
    for graph in manifest.graphs():
        model = onnx.load(bundle / graph.file)
        counts = collections.Counter(node.op_type for node in model.graph.node)
        union |= set(counts)
        opsets = ", ".join(f"{o.domain or 'ai.onnx'} {o.version}" for o in model.opset_import)
        rows.append(
            f"| {graph.file} | {opsets} | "
            + ", ".join(f"{op} {n}" for op, n in sorted(counts.items()))
            + " |"
        )
    return "\n".join(rows) + f"\n\nEvery op used ({len(union)}): {', '.join(sorted(union))}.\n"


def _agreement(int8: MotionGenerator, portable: MotionGenerator) -> str:
    """Teacher-forced greedy agreement, as `mogo export` measures int8 against fp32."""
    greedy = Sampling(temperature=0)
    same = total = 0
    for prompt in AGREEMENT_PROMPTS:
        embedding = int8.embed([prompt])[0]
        reference = int8.tokens.generate(embedding, AGREEMENT_STEPS, sampling=greedy)
        for n in range(AGREEMENT_STEPS):
            stream = portable.tokens.start(embedding, sampling=greedy, allow_end=False)
            if n:
                stream.continue_from(reference[:n])
            same += int(np.sum(stream.step() == reference[n]))
            total += reference.shape[1]
    return (
        f"Greedy tokens, teacher-forced on the int8 bundle's stream ({len(AGREEMENT_PROMPTS)}"
        f" prompts x {AGREEMENT_STEPS} steps x 6 levels): the portable bundle picks the "
        f"same token {same / total:.1%} of the time ({same}/{total}).\n"
    )


def _runtime_speed(generators: dict[str, MotionGenerator]) -> str:
    calls = {
        name: functools.partial(g.generate, PROMPT, seconds=SECONDS, seed=SEED)
        for name, g in generators.items()
    }
    log("timing our runtime")
    seconds = interleaved(calls, rounds=7, budget_s=60.0)
    frames = round(SECONDS * SMPL_22.fps)
    base = seconds["int8 (shipped)"]
    rows = ["| bundle | s per 5-s clip | frames/s | time vs int8 |", "|---|---|---|---|"]
    rows += [
        f"| {name} | {s:.2f} | {frames / s:.0f} | {s / base:.2f}x |" for name, s in seconds.items()
    ]
    return (
        "Our runtime, `generate` of a 5-s walk (feet planted), 1 thread, medians of "
        "interleaved rounds:\n\n" + "\n".join(rows) + "\n"
    )


_NODE_SCRIPT = """
import { readFile } from "node:fs/promises";
import { join } from "node:path";
import * as ort from "%(web)s/vendor/ort.wasm.min.mjs";
import { Bundle } from "%(web)s/mogo.mjs";
ort.env.wasm.numThreads = 1;
const dir = %(bundle)s, query = %(query)s;
const b = await Bundle.load(ort, async (n) => new Uint8Array(await readFile(join(dir, n))));
const sampling = { ...b.manifest.defaults };
const embedding = Float32Array.from(query.embedding);
await b.generate(embedding, query.seconds, query.seed, sampling);  // warm-up
const times = [];
for (let k = 0; k < 3; k++) {
  const start = performance.now();
  await b.generate(embedding, query.seconds, query.seed, sampling);
  times.push((performance.now() - start) / 1000);
}
const L = 6, n = query.tokens.length + 1, logits = [];
for (let level = 0; level < L; level++) {
  const [layers, heads, dim] = b.cacheShape(level);
  const rows = [Array(L).fill(0), ...query.tokens];
  const feed = [
    new ort.Tensor("float32", embedding, [1, embedding.length]),
    new ort.Tensor("bool", Uint8Array.from([0]), [1]),
    new ort.Tensor("int64", BigInt64Array.from(rows.flat().map(BigInt)), [1, n, L]),
    new ort.Tensor("int64", BigInt64Array.from(rows.map((_, i) => BigInt(i))), [n]),
    new ort.Tensor("int64", new BigInt64Array(0), [0]),
    ...Array.from({ length: 2 * layers },
      () => new ort.Tensor("float32", new Float32Array(0), [1, heads, 0, dim]))];
  logits.push(Array.from((await b.runLevel(level, feed))[0].data));
}
console.log(JSON.stringify({ times, logits }));
"""


def _node(bundle: Path, generator: MotionGenerator) -> str:
    """The port under Node: a 5-s clip's time, and the logits of every level after 39
    teacher-forced steps of the walk against our runtime's (the float difference across
    engines that docs/spec.md §9 quotes)."""
    embedding = generator.embed([PROMPT])[0]
    tokens = generator.tokens.generate(embedding, 39, sampling=generator.sampling(), seed=SEED)
    query = dict(embedding=embedding.tolist(), seconds=SECONDS, seed=SEED, tokens=tokens.tolist())
    script = _NODE_SCRIPT % dict(web=WEB, bundle=json.dumps(str(bundle)), query=json.dumps(query))
    log("timing the port under Node")
    result = json.loads(
        subprocess.run(
            ["node", "--input-type=module"],
            input=script,
            capture_output=True,
            text=True,
            check=True,
            timeout=600,
        ).stdout
    )
    rows = np.concatenate([np.zeros((1, 6), np.int64), tokens])
    largest = 0.0
    for level in range(6):
        ours, _ = generator.tokens.run(
            level,
            embedding[None],
            np.array([False]),
            rows[None],
            np.arange(len(rows)),
            np.zeros(0, np.int64),
            generator.tokens.empty_cache(level, 1),
        )
        largest = max(largest, float(np.abs(ours[0] - np.array(result["logits"][level])).max()))
    s = float(np.median(result["times"]))
    return (
        f"The JavaScript port under Node {_version(['node', '--version'])} "
        f"(onnxruntime-web, WebAssembly, 1 thread): a 5-s clip (131 token steps, the decode "
        f"and the feet, the embedding given) in {s:.2f} s, "
        f"{round(SECONDS * SMPL_22.fps) / s:.0f} frames/s (median of 3). Largest logit difference "
        f"from our runtime over the 6 levels after 40 teacher-forced positions: "
        f"{largest:.1e}.\n"
    )


def _browser(bundle: Path) -> str:
    log("timing the page in headless Chromium")
    with page_site(bundle) as site, headless_chromium() as browser:
        results = []
        for _ in range(3):
            browser.get(page_url(site, prompt=PROMPT, seconds=SECONDS, seed=SEED))
            results.append(wait_for(browser, "mogoResult"))
    s = float(np.median([r["totalSeconds"] for r in results]))
    load = float(np.median([r["loadSeconds"] for r in results]))
    return (
        f"The page in headless Chromium {_version([CHROMIUM, '--version'])}: the bundle "
        f"loaded in {load:.1f} s, then a 5-s clip from prompt text (tokenizer, trained "
        f"encoder, 131 token steps, decode, feet) in {s:.2f} s, {round(SECONDS * SMPL_22.fps) / s:.0f} "
        "frames/s (median of 3 page loads).\n"
    )


def _version(command: list[str]) -> str:
    return subprocess.run(command, capture_output=True, text=True, check=False).stdout.strip()


if __name__ == "__main__":
    main()
