// The reference port of mogo's `generate` (docs/spec.md) on onnxruntime-web: a portable
// bundle (`mogo export --portable`) in, joint positions out, in a browser or Node. Feet are
// not planted (mogo.motion.feet is not ported). The caller passes the onnxruntime module
// (`ort`) and a `read(name)` that returns a bundle file's bytes (fetch or fs).

// -- the random stream: numpy's PCG64 seeded by SeedSequence (spec §2) ---------------------
const M32 = 0xffffffff;
const mul32 = (a, b) => Math.imul(a, b) >>> 0;

function seedWords(seed) {
  // SeedSequence(seed).generate_state(4, uint64) as 8 little-endian uint32 words
  let entropy = [];
  for (let s = BigInt(seed); ; s >>= 32n) {
    entropy.push(Number(s & 0xffffffffn));
    if (s < 0x100000000n) break;
  }
  let hashConst = 0x43b0d7e5;
  const hashmix = (value) => {
    value = (value ^ hashConst) >>> 0;
    hashConst = mul32(hashConst, 0x931e8875);
    value = mul32(value, hashConst);
    return (value ^ (value >>> 16)) >>> 0;
  };
  const mix = (x, y) => {
    const r = (mul32(0xca01f9dd, x) - mul32(0x4973f715, y)) >>> 0;
    return (r ^ (r >>> 16)) >>> 0;
  };
  const pool = [0, 1, 2, 3].map((i) => hashmix(i < entropy.length ? entropy[i] : 0));
  for (let src = 0; src < 4; src++)
    for (let dst = 0; dst < 4; dst++)
      if (src !== dst) pool[dst] = mix(pool[dst], hashmix(pool[src]));
  for (let src = 4; src < entropy.length; src++)
    for (let dst = 0; dst < 4; dst++) pool[dst] = mix(pool[dst], hashmix(entropy[src]));
  let constB = 0x8b51f9dd;
  const words = [];
  for (let i = 0; i < 8; i++) {
    let v = (pool[i % 4] ^ constB) >>> 0;
    constB = mul32(constB, 0x58f38ded);
    v = mul32(v, constB);
    words.push((v ^ (v >>> 16)) >>> 0);
  }
  return words;
}

const MASK128 = (1n << 128n) - 1n;
const MULT = 0x2360ed051fc65da44385df649fccf645n;

export class PCG64 {
  constructor(seed) {
    const w = seedWords(seed).map(BigInt);
    const u64 = (k) => w[2 * k] | (w[2 * k + 1] << 32n);
    const initstate = (u64(0) << 64n) | u64(1);
    const initseq = (u64(2) << 64n) | u64(3);
    this.inc = ((initseq << 1n) | 1n) & MASK128;
    this.state = 0n;
    this.step();
    this.state = (this.state + initstate) & MASK128;
    this.step();
  }
  step() {
    this.state = (this.state * MULT + this.inc) & MASK128;
  }
  next64() {
    this.step();
    const rot = this.state >> 122n;
    const x = ((this.state >> 64n) ^ this.state) & 0xffffffffffffffffn;
    return ((x >> rot) | (x << ((64n - rot) & 63n))) & 0xffffffffffffffffn;
  }
  random() {
    return Number(this.next64() >> 11n) / 9007199254740992;
  }
}

// -- the sampler: mogo.sampling's float64 rule (spec §4) -----------------------------------
export function chooseToken(cond, uncond, uniform, s, forbid) {
  const K = cond.length;
  const z = new Float64Array(K);
  for (let k = 0; k < K; k++) {
    const c = cond[k];
    if (s.guidance !== 1) {
      const u = uncond[k];
      z[k] = c === -Infinity && u === -Infinity ? -Infinity : u + s.guidance * (c - u);
    } else z[k] = c;
  }
  if (forbid !== null && forbid !== undefined) z[forbid] = -Infinity;
  if (s.temperature === 0) {
    let best = 0;
    for (let k = 1; k < K; k++) if (z[k] > z[best]) best = k;
    return best;
  }
  for (let k = 0; k < K; k++) z[k] = z[k] / s.temperature;
  const order = Array.from({ length: K }, (_, k) => k);
  order.sort((a, b) => (z[b] - z[a]) || (a - b) || 0);
  const sorted = order.map((k) => z[k]);
  let keep = sorted.filter(Number.isFinite).length;
  if (s.top_k) keep = Math.min(keep, s.top_k, K);
  const p = new Float64Array(K);
  const c = new Float64Array(K);
  let sum = 0;
  for (let i = 0; i < K; i++) {
    p[i] = i < keep ? Math.exp(sorted[i] - sorted[0]) : 0;
    sum += p[i];
    c[i] = sum;
  }
  if (s.top_p < 1) {
    const cut = s.top_p * c[keep - 1];
    let kept = 0;
    for (let i = 0; i < keep; i++) if (c[i] - p[i] < cut) kept++;
    keep = kept;
  }
  const target = uniform * c[keep - 1];
  let index = 0;
  for (let i = 0; i < K; i++) if (c[i] <= target) index++;
  return order[index];
}

// -- features to joints: mogo.motion.features.features_to_joints (spec §7) ----------------
function qrot(w, ux, uy, uz, v) {
  const cx = uy * v[2] - uz * v[1], cy = uz * v[0] - ux * v[2], cz = ux * v[1] - uy * v[0];
  const dx = uy * cz - uz * cy, dy = uz * cx - ux * cz, dz = ux * cy - uy * cx;
  return [v[0] + 2 * (w * cx + dx), v[1] + 2 * (w * cy + dy), v[2] + 2 * (w * cz + dz)];
}

export function featuresToJoints(features, frames, dim, joints) {
  // features: Float64Array (frames * dim); returns Float32Array (frames * joints * 3)
  const out = new Float32Array(frames * joints * 3);
  let half = 0, x = 0, z = 0;
  for (let t = 0; t < frames; t++) {
    const f = (i) => features[t * dim + i];
    if (t > 0) {
      half += features[(t - 1) * dim];
      const step = qrot(Math.cos(half), 0, -Math.sin(half), 0,
        [features[(t - 1) * dim + 1], 0, features[(t - 1) * dim + 2]]);
      x += step[0];
      z += step[2];
    }
    const w = Math.cos(half), uy = -Math.sin(half);
    const base = t * joints * 3;
    out[base] = x; out[base + 1] = f(3); out[base + 2] = z;
    for (let j = 1; j < joints; j++) {
      const r = qrot(w, 0, uy, 0, [f(4 + 3 * (j - 1)), f(5 + 3 * (j - 1)), f(6 + 3 * (j - 1))]);
      out[base + 3 * j] = r[0] + x; out[base + 3 * j + 1] = r[1]; out[base + 3 * j + 2] = r[2] + z;
    }
  }
  return out;
}

// -- .npy (float32, little-endian) ----------------------------------------------------------
export function readNpy(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const headerLength = view.getUint16(8, true);
  const header = new TextDecoder().decode(bytes.subarray(10, 10 + headerLength));
  if (!header.includes("'<f4'")) throw new Error(`.npy: not little-endian float32: ${header}`);
  const start = bytes.byteOffset + 10 + headerLength;
  return new Float32Array(bytes.buffer.slice(start, bytes.byteOffset + bytes.byteLength));
}

// -- the bundle and the token loop (spec §3, §5, §6) ---------------------------------------
export class Bundle {
  static async load(ort, read) {
    const b = new Bundle();
    b.ort = ort;
    b.manifest = JSON.parse(new TextDecoder().decode(await read("manifest.json")));
    const m = b.manifest;
    const options = { executionProviders: ["wasm"], graphOptimizationLevel: "all" };
    b.levels = [];
    for (const level of m.t2m.levels)
      b.levels.push({ graph: level, session: await ort.InferenceSession.create(await read(level.file), options) });
    b.decoder = await ort.InferenceSession.create(await read(m.vq.decoder.file), options);
    b.mean = readNpy(await read(m.motion.normalization.mean));
    b.std = readNpy(await read(m.motion.normalization.std));
    b.endToken = m.vq.config.codebook_size;
    b.read = read;
    return b;
  }

  cacheShape(level) {
    // (layers, heads, head_dim) from the session's past inputs: the manifest names them;
    // heads and head_dim are the graph's fixed sizes, read from the config here
    const graph = this.levels[level].graph;
    const pasts = graph.inputs.length - 5;
    const c = this.manifest.t2m.config;
    return [pasts / 2, c.heads[level], c.head_dim];
  }

  async runLevel(level, feed) {
    const { graph, session } = this.levels[level];
    const inputs = {};
    graph.inputs.forEach((name, i) => { inputs[name] = feed[i]; });
    const out = await session.run(inputs);
    return graph.outputs.map((name) => out[name]);
  }

  // prompt embedding (Float32Array) -> token ids (steps x L) as arrays, `generate` §5
  async generateTokens(embedding, steps, sampling, seed, window, onStep) {
    const ort = this.ort, L = this.levels.length, guided = sampling.guidance !== 1;
    const B = guided ? 2 : 1;
    const rng = new PCG64(seed);
    const prompt = new ort.Tensor("float32", Float32Array.from({ length: B * embedding.length },
      (_, i) => embedding[i % embedding.length]), [B, embedding.length]);
    const uncond = new ort.Tensor("bool", Uint8Array.from([0, 1].slice(0, B)), [B]);
    let caches = this.levels.map((_, level) => {
      const [layers, heads, dim] = this.cacheShape(level);
      return Array.from({ length: 2 * layers },
        () => new ort.Tensor("float32", new Float32Array(0), [B, heads, 0, dim]));
    });
    let positions = [];
    let last = new Array(L).fill(0);
    let oldest = 1;
    const rows = [];
    for (let n = 0; n < steps; n++) {
      const uniforms = Array.from({ length: L }, () => rng.random());
      const ids = new ort.Tensor("int64", BigInt64Array.from(
        { length: B * L }, (_, i) => BigInt(last[i % L])), [B, 1, L]);
      const position = new ort.Tensor("int64", BigInt64Array.from([BigInt(n)]), [1]);
      const past = new ort.Tensor("int64", BigInt64Array.from(positions.map(BigInt)), [positions.length]);
      const outputs = [];
      for (let level = 0; level < L; level++)
        outputs.push(await this.runLevel(level, [prompt, uncond, ids, position, past, ...caches[level]]));
      const row = outputs.map(([logits], level) => {
        const K = logits.dims[1], data = logits.data;
        return chooseToken(data.subarray(0, K), guided ? data.subarray(K, 2 * K) : null,
          uniforms[level], sampling, level === 0 ? this.endToken : null);
      });
      const presents = outputs.map(([, ...p]) => p);
      if (window !== null && positions.length === 1 + window) {
        const slot = oldest;
        presents.forEach((levelPresents, level) => levelPresents.forEach((present, k) => {
          const held = caches[level][k];
          const [b, h, p, d] = held.dims;
          for (let i = 0; i < b * h; i++)
            held.data.set(present.data.subarray((i * (p + 1) + p) * d, (i * (p + 1) + p + 1) * d),
              (i * p + slot) * d);
        }));
        positions[slot] = n;
        oldest = (slot % window) + 1;
      } else {
        caches = presents;
        positions.push(n);
      }
      last = row;
      rows.push(row);
      if (onStep) onStep(n, row);
    }
    return rows;
  }

  // token ids (steps x L) -> joints of the first `frames` frames (spec §6, §7)
  async decode(rows, frames) {
    const ort = this.ort, L = this.levels.length;
    const dec = this.manifest.vq.decoder;
    const ids = new ort.Tensor("int64", BigInt64Array.from(rows.flat().map(BigInt)), [1, rows.length, L]);
    const out = await this.decoder.run({ [dec.inputs[0]]: ids });
    const normalised = out[dec.outputs[0]];
    const D = normalised.dims[2];
    const n = Math.min(frames, normalised.dims[1]);
    const features = new Float64Array(n * D);
    for (let i = 0; i < n * D; i++)
      features[i] = Math.fround(Math.fround(normalised.data[i] * this.std[i % D]) + this.mean[i % D]);
    return featuresToJoints(features, n, D, this.manifest.motion.skeleton.joint_names.length);
  }

  // `generate` of a clip of `seconds` (spec §5): the lookahead's steps drawn beyond it
  async generate(embedding, seconds, seed, sampling, window, onStep) {
    const m = this.manifest, fps = m.motion.fps;
    const frames = Math.round(seconds * fps);
    const steps = Math.max(1, Math.ceil(frames / m.vq.config.down_factor)) + m.vq.decoder.lookahead;
    const rows = await this.generateTokens(embedding, steps, sampling, seed,
      window === undefined ? m.defaults.window : window, onStep);
    return { rows, frames, joints: await this.decode(rows, frames) };
  }

  // prompt text -> embedding by the encoder trained with the model (manifest text.trained),
  // for a prompt it reads whole: every word one token of its vocabulary, nothing cut at its
  // length (spec §1); null otherwise. Digits are not spelt out as mogo does ("2" -> "two").
  async embedTrained(Tokenizer, text) {
    const trained = this.manifest.text.trained;
    if (!this._trained) {
      const json = JSON.parse(new TextDecoder().decode(await this.read(trained.tokenizer)));
      this._trained = {
        tokenizer: new Tokenizer(json, {}),
        unknown: json.model.unk_token,
        maxLength: json.truncation ? json.truncation.max_length : Infinity,
        session: await this.ort.InferenceSession.create(await this.read(trained.encoder.file),
          { executionProviders: ["wasm"] }),
      };
    }
    const { tokenizer, unknown, maxLength, session } = this._trained;
    const encoded = tokenizer.encode(text);
    const pieces = encoded.tokens.some((t) => t === unknown || t.startsWith("##"));
    if (pieces || encoded.ids.length > maxLength) return null;
    const ids = new this.ort.Tensor("int64", BigInt64Array.from(encoded.ids.map(BigInt)), [1, encoded.ids.length]);
    const mask = new this.ort.Tensor("int64", BigInt64Array.from(encoded.attention_mask.map(BigInt)), [1, encoded.ids.length]);
    const [idsName, maskName] = trained.encoder.inputs;
    const out = await session.run({ [idsName]: ids, [maskName]: mask });
    return out[trained.encoder.outputs[0]].data;
  }
}

// -- the conformance rule (mogo.export.onnx.conformance.compare_tokens) --------------------
export function compareTokens(c, rows, tolerances) {
  const tie = c.sampling.temperature === 0 ? tolerances.tie_logit : tolerances.tie_mass;
  for (let n = 0; n < c.tokens.length; n++)
    for (let l = 0; l < c.tokens[n].length; l++)
      if (rows[n][l] !== c.tokens[n][l]) {
        if (c.margins[n][l] < tie) return { agreed: n, problem: null };
        return { agreed: n, problem: `${c.name}: step ${n} level ${l}: token ${rows[n][l]}, expected ${c.tokens[n][l]} (margin ${c.margins[n][l]}, no tie)` };
      }
  return { agreed: c.tokens.length, problem: null };
}

// Every case of the vectors against this port; returns a report (problems: [] when it passes)
export async function checkConformance(bundle, vectors, log = () => {}) {
  const problems = [], report = { problems, cases: [] };
  for (const c of vectors.random) {
    const rng = new PCG64(c.seed);
    c.uniforms.forEach((u, i) => {
      const mine = rng.random();
      if (mine !== u) problems.push(`random seed ${c.seed} draw ${i}: ${mine}, expected ${u}`);
    });
  }
  vectors.sampler.forEach((c, i) => {
    const token = chooseToken(Float32Array.from(c.cond), c.uncond && Float32Array.from(c.uncond),
      c.uniform, c.sampling, c.forbid);
    if (token !== c.token) problems.push(`sampler case ${i}: token ${token}, expected ${c.token}`);
  });
  for (const c of vectors.generate) {
    const start = performance.now();
    const rows = await bundle.generateTokens(Float32Array.from(c.prompt_embedding), c.steps,
      c.sampling, c.seed, c.window);
    const seconds = (performance.now() - start) / 1000;
    const { agreed, problem } = compareTokens(c, rows, vectors.tolerances);
    if (problem) problems.push(problem);
    let jointsDifference = null;
    if (agreed === c.steps) {
      const joints = await bundle.decode(rows, c.frames);
      const expected = c.joints.flat(2);
      jointsDifference = 0;
      expected.forEach((v, i) => { jointsDifference = Math.max(jointsDifference, Math.abs(joints[i] - v)); });
      if (!(jointsDifference < vectors.tolerances.joints_m))
        problems.push(`${c.name}: joints differ by ${jointsDifference} m`);
    }
    report.cases.push({ name: c.name, steps: c.steps, agreed, jointsDifference, tokenSeconds: seconds });
    log(`${c.name}: ${agreed}/${c.steps} steps agree, joints ${jointsDifference}, ${seconds.toFixed(2)} s`);
  }
  return report;
}
