// The reference port of mogo's `generate`, `play` and streams (docs/spec.md) on
// onnxruntime-web: a portable bundle (`mogo export portable`) in, joint positions out, in a
// browser or Node, the feet planted, streams re-anchored (mogo.anchoring's words from
// words.json). Not ported: the sentence encoder for prompts in other words (spec §11). The
// caller passes the onnxruntime module (`ort`) and a `read(name)` that returns a bundle
// file's bytes (fetch or fs).

// -- the random stream: numpy's PCG64 seeded by SeedSequence (spec §2) ---------------------
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

export class JointStream {
  // features (n x D, Float64Array) in any chunks -> joints (n x J x 3, Float32Array), the
  // root's yaw half-angle and XZ carried from chunk to chunk (mogo.motion.features.JointStream)
  constructor(dim, joints) {
    this.dim = dim; this.joints = joints;
    this.half = 0; this.x = 0; this.z = 0; this.previous = null;
  }
  push(features, frames) {
    const D = this.dim, J = this.joints, out = new Float32Array(frames * J * 3);
    for (let t = 0; t < frames; t++) {
      const f = (i) => features[t * D + i];
      if (this.previous) {
        const p = this.previous;
        this.half += p[0];
        const step = qrot(Math.cos(this.half), 0, -Math.sin(this.half), 0, [p[1], 0, p[2]]);
        this.x += step[0];
        this.z += step[2];
      }
      this.previous = [f(0), f(1), f(2)];
      const w = Math.cos(this.half), uy = -Math.sin(this.half), base = t * J * 3;
      out[base] = this.x; out[base + 1] = f(3); out[base + 2] = this.z;
      for (let j = 1; j < J; j++) {
        const r = qrot(w, 0, uy, 0, [f(1 + 3 * j), f(2 + 3 * j), f(3 + 3 * j)]);
        out[base + 3 * j] = r[0] + this.x; out[base + 3 * j + 1] = r[1];
        out[base + 3 * j + 2] = r[2] + this.z;
      }
    }
    return out;
  }
}

// -- feet: mogo.motion.feet.FootPlanter, for clips (plant) and streams (push) (spec §7) ----
const CONTACT = 0.5, HOLD_STEP2 = Math.pow(Math.pow(0.002, 0.5), 2), BLEND_IN = 3;
const BLEND_OUT = 8, PIN_FRAMES = 6, MAX_REACH = 0.9995, KNEE_FORWARD = 0.1;
const LOOKAHEAD = BLEND_IN + PIN_FRAMES - 1;  // frames read ahead (8)
const ease = (x) => { x = Math.min(1, Math.max(0, x)); return x * x * (3 - 2 * x); };
const norm = (v) => Math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
const add3 = (a, b, s = 1) => [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]];

function twoBoneIK(hip, target, pole, upper, lower) {
  const reach = add3(target, hip, -1);
  let distance = norm(reach);
  const axis = reach.map((c) => c / Math.max(distance, 1e-9));
  distance = Math.min(Math.max(distance, Math.abs(upper - lower) + 1e-6), MAX_REACH * (upper + lower));
  let side = add3(pole, hip, -1);
  const along = side[0] * axis[0] + side[1] * axis[1] + side[2] * axis[2];
  side = add3(side, axis, -along);
  const sideNorm = norm(side);
  if (sideNorm > 1e-6) side = side.map((c) => c / Math.max(sideNorm, 1e-9));
  else {
    const fallback = [0, axis[2], -axis[1]], n = Math.max(norm(fallback), 1e-9);
    side = fallback.map((c) => c / n);
  }
  const cos = (upper * upper + distance * distance - lower * lower) / (2 * upper * distance);
  const sin = Math.sqrt(Math.min(Math.max(1 - cos * cos, 0), 1));
  const knee = hip.map((h, i) => h + upper * (cos * axis[i] + sin * side[i]));
  return [knee, hip.map((h, i) => h + distance * axis[i])];
}

export class FootPlanter {
  constructor(manifest) {
    const sk = manifest.motion.skeleton, names = sk.joint_names, parents = sk.parents;
    this.legs = [sk.left_foot, sk.right_foot].map(([ankle, toe]) => {
      const knee = parents[ankle];
      return [parents[knee], knee, ankle, toe];
    });
    this.contacts = this.legs.flatMap((leg) => leg.slice(2));  // left ankle, toe, right ...
    const velocity = manifest.motion.features.find((b) => b.name === "joint_velocities").start;
    this.velocity = this.contacts.map((j) => velocity + 3 * j);
    this.hips = sk.face_joints.slice(0, 2);  // right hip, left hip
    const mirror = (j) => names.indexOf(names[j].startsWith("left_") ? names[j].replace("left_", "right_")
      : names[j].startsWith("right_") ? names[j].replace("right_", "left_") : names[j]);
    const length = (j) => {  // the rig's symmetric rest bone (mogo.motion.rig.rest_offsets)
      const a = sk.rest_offsets[j], b = sk.rest_offsets[mirror(j)];
      return norm([(a[0] - b[0]) / 2, (a[1] + b[1]) / 2, (a[2] + b[2]) / 2]);
    };
    this.lengths = this.legs[0].slice(1).map(length);  // thigh, shin, foot
    this.D = manifest.motion.features.at(-1).stop;
    this.J = names.length;
    this.reset();
  }

  // a whole clip: features (Float64Array n x D), joints (Float32Array n x J x 3) -> joints
  plant(features, joints, n) {
    this.reset();
    const first = this.push(features, joints, n), rest = this.flush();
    const all = new Float32Array(first.length + rest.length);
    all.set(first); all.set(rest, first.length);
    return all;
  }

  reset() {
    this.state = this.contacts.map(() => ({ flag: false, held: false, pin: [0, 0, 0],
                                           released: [0, 0, 0], since: 2 ** 30 }));
    this.features = []; this.joints = [];  // the buffered rows
  }

  // rows in, the rows now final out (joints), LOOKAHEAD frames held back for the pins ahead
  push(features, joints, n) {
    if (!n) return new Float32Array(0);
    for (let i = 0; i < n; i++) {
      this.features.push(features.subarray(i * this.D, (i + 1) * this.D));
      this.joints.push(joints.subarray(i * this.J * 3, (i + 1) * this.J * 3));
    }
    return this.clean(Math.max(0, this.features.length - LOOKAHEAD));
  }

  // the stream's end: the rows held back
  flush() {
    return this.clean(this.features.length);
  }

  clean(ready) {
    const n = this.features.length, K = this.contacts.length, D = this.D, J = this.J;
    const at = (i, j) => Array.from(this.joints[i].subarray(3 * j, 3 * j + 3));
    const flags = [], held = [], paths = [];
    for (let i = 0; i < n; i++) {
      const f = this.features[i];
      flags.push(this.contacts.map((_, k) => {
        let speed = 0;
        for (let c = 0; c < 3; c++) speed += f[this.velocity[k] + c] ** 2;
        return f[D - 4 + k] > CONTACT && speed < HOLD_STEP2;
      }));
      paths.push(this.contacts.map((j) => at(i, j)));
    }
    for (let i = 0; i < n; i++)
      held.push(flags[i].map((f, k) => f || (i > 0 ? flags[i - 1][k] : this.state[k].flag)));
    const targets = [], weights = [];
    for (let k = 0; k < K; k++) {
      const state = this.state[k];
      let pin = state.pin, last = -1;
      const offsets = [], pins = [];
      for (let i = 0; i < n; i++) {
        const before = i > 0 ? held[i - 1][k] : state.held;
        if (held[i][k] && !before) {  // a contact starts: its pin (where frames out need it)
          pin = state.pin;
          if (i < ready + BLEND_IN) {
            let length = 0;
            while (length < PIN_FRAMES && i + length < n && held[i + length][k]) length++;
            pin = [0, 0, 0];
            for (let f = i; f < i + length; f++) pin = add3(pin, paths[f][k]);
            pin = pin.map((c) => c / length);
          }
        }
        pins.push(pin);
        const o = add3(pin, paths[i][k], -1);
        o[1] = Math.max(o[1], 0);
        offsets.push(o);
      }
      let since, released;
      for (let i = 0; i < ready; i++) {
        since = last >= 0 ? i - last : state.since + i + 1;
        released = last >= 0 ? offsets[last] : state.released;
        const out = ease(1 - since / (BLEND_OUT + 1));
        let following = n;
        for (let f = i + 1; f < n; f++) if (flags[f][k]) { following = f; break; }
        const into = following < n ? ease(1 - (following - i) / (BLEND_IN + 1)) : 0;
        const start = offsets[Math.min(following, n - 1)];
        let offset = released.map((r, c) => out * r + into * start[c]);
        let weight = out + into;
        offset = offset.map((c) => c / Math.max(weight, 1));
        if (held[i][k]) { offset = offsets[i]; weight = 1; } else weight = Math.min(weight, 1);
        (targets[i] ||= [])[k] = add3(paths[i][k], offset);
        (weights[i] ||= [])[k] = weight;
        if (held[i][k]) last = i;
      }
      if (ready) {  // the state after the last frame out
        const end = ready - 1;
        this.state[k] = { flag: flags[end][k], held: held[end][k], pin: pins[end],
                          released: held[end][k] ? offsets[end] : released,
                          since: held[end][k] ? 0 : since };
      }
    }
    const result = new Float32Array(ready * J * 3);
    for (let i = 0; i < ready; i++) result.set(this.joints[i], i * J * 3);
    const [thigh, shin, foot] = this.lengths;
    for (let i = 0; i < ready; i++) {
      const across = add3(at(i, this.hips[0]), at(i, this.hips[1]), -1);
      let forward = [across[2], 0, -across[0]];
      const fn = KNEE_FORWARD / Math.max(norm(forward), 1e-9);
      forward = forward.map((c) => c * fn);
      this.legs.forEach(([hip, knee, ankle, toe], leg) => {
        let a = targets[i][2 * leg];
        const t = targets[i][2 * leg + 1], wa = weights[i][2 * leg], wt = weights[i][2 * leg + 1];
        let along = add3(t, a, -1);
        const span = norm(along);
        along = along.map((c) => c / Math.max(span, 1e-9));
        const total = wa + wt, toeShare = total > 0 ? wt / Math.max(total, 1e-9) : 0.5;
        a = add3(a, along, toeShare * (span - foot));
        a[1] += Math.max(0, -Math.min(a[1], a[1] + foot * along[1]));
        const [k, an] = twoBoneIK(at(i, hip), a, add3(at(i, knee), forward), thigh, shin);
        const tip = add3(an, along, foot);
        for (const [j, v] of [[knee, k], [ankle, an], [toe, tip]])
          for (let c = 0; c < 3; c++) result[(i * J + j) * 3 + c] = v[c];
      });
    }
    this.features = this.features.slice(ready);
    this.joints = this.joints.slice(ready);
    return result;
  }
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

// -- the bundle (spec §3, §6) ---------------------------------------------------------------
export class Bundle {
  static async load(ort, read) {
    const b = new Bundle();
    b.ort = ort;
    b.read = read;
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
    b.numJoints = m.motion.skeleton.joint_names.length;
    return b;
  }

  cacheShape(level) {
    // (layers, heads, head_dim): the manifest names the past inputs, the config their sizes
    const c = this.manifest.t2m.config;
    return [(this.levels[level].graph.inputs.length - 5) / 2, c.heads[level], c.head_dim];
  }

  async runLevel(level, feed) {
    const { graph, session } = this.levels[level];
    const inputs = {};
    graph.inputs.forEach((name, i) => { inputs[name] = feed[i]; });
    const out = await session.run(inputs);
    return graph.outputs.map((name) => out[name]);
  }

  // token rows (n x L) -> denormalised features (Float64Array, frames x D), float32 arithmetic
  async decodeFeatures(rows) {
    const L = this.levels.length, dec = this.manifest.vq.decoder;
    const ids = new this.ort.Tensor("int64", BigInt64Array.from(rows.flat().map(BigInt)), [1, rows.length, L]);
    const normalised = (await this.decoder.run({ [dec.inputs[0]]: ids }))[dec.outputs[0]];
    const D = normalised.dims[2], features = new Float64Array(normalised.data.length);
    for (let i = 0; i < features.length; i++)
      features[i] = Math.fround(Math.fround(normalised.data[i] * this.std[i % D]) + this.mean[i % D]);
    return features;
  }

  // token rows -> joints of the first `frames` frames, offline, the feet planted unless
  // plantFeet is false (spec §6, §7)
  async decode(rows, frames, plantFeet = true) {
    const D = this.mean.length, J = this.numJoints, features = await this.decodeFeatures(rows);
    const n = Math.min(frames, features.length / D);
    const joints = new JointStream(D, J).push(features, n);
    return plantFeet ? new FootPlanter(this.manifest).plant(features, joints, n) : joints;
  }

  steps(seconds) {
    const m = this.manifest;
    return Math.max(1, Math.ceil(Math.round(seconds * m.motion.fps) / m.vq.config.down_factor));
  }

  // `generate` of a clip of `seconds` (spec §5): the lookahead's steps drawn beyond it
  async generate(embedding, seconds, seed, sampling, window, plantFeet = true) {
    return this.play([[embedding, seconds]], seed, sampling, window, plantFeet);
  }

  // `play`: [[embedding, seconds], ...] as one stream, the prompt switched between entries
  // (spec §8), cut after the last with the lookahead's steps as its right context
  async play(schedule, seed, sampling, window, plantFeet = true) {
    const stream = new TokenStream(this, schedule[0][0], seed, sampling,
      window === undefined ? this.manifest.defaults.window : window);
    const rows = [];
    for (const [k, [embedding, seconds]] of schedule.entries()) {
      if (k) await stream.setPrompt(embedding);
      for (let n = this.steps(seconds); n > 0; n--) rows.push(await stream.step());
    }
    const frames = rows.length * this.manifest.vq.config.down_factor;
    for (let n = this.manifest.vq.decoder.lookahead; n > 0; n--) rows.push(await stream.step());
    return { rows, frames, joints: await this.decode(rows, frames, plantFeet) };
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

// -- the token loop: one stream's prompt, random state and KV cache (spec §5, §8) -----------
export class TokenStream {
  constructor(bundle, embedding, seed, sampling, window) {
    const ort = bundle.ort;
    this.bundle = bundle; this.sampling = sampling; this.window = window;
    this.L = bundle.levels.length;
    this.B = sampling.guidance !== 1 ? 2 : 1;
    this.rng = new PCG64(seed);
    this.uncond = new ort.Tensor("bool", Uint8Array.from([0, 1].slice(0, this.B)), [this.B]);
    this.prompt = this.batch(embedding);
    this.allowEnd = false;  // level 0 may draw the end token (from step 1 on): step() -> null
    this.restart();
  }

  // forget every step drawn (not the random state): the next step is step 0 of a fresh clip
  restart() {
    this.caches = this.bundle.levels.map((_, level) => this.emptyCache(level));
    this.positions = [];  // the position of every cache slot
    this.slotTokens = [];  // the tokens each slot holds (the prefix: zeros)
    this.last = new Array(this.L).fill(0);
    this.steps = 0;
    this.oldest = 1;
  }

  // `rows` (n x L) as the steps drawn so far, in place of anything drawn before (n <= 1 + W)
  async continueFrom(rows) {
    const n = rows.length;
    this.positions = Array.from({ length: n }, (_, i) => i);
    this.slotTokens = [new Array(this.L).fill(0), ...rows.slice(0, -1)];
    this.last = rows[n - 1];
    this.steps = n;
    this.oldest = 1;
    await this.prefill();
  }

  batch(embedding) {
    return new this.bundle.ort.Tensor("float32", Float32Array.from(
      { length: this.B * embedding.length }, (_, i) => embedding[i % embedding.length]),
      [this.B, embedding.length]);
  }

  emptyCache(level) {
    const [layers, heads, dim] = this.bundle.cacheShape(level);
    return Array.from({ length: 2 * layers },
      () => new this.bundle.ort.Tensor("float32", new Float32Array(0), [this.B, heads, 0, dim]));
  }

  int64(values, dims) {
    return new this.bundle.ort.Tensor("int64", BigInt64Array.from(values.map(BigInt)), dims);
  }

  // the tokens (L) of the next step, or null where level 0 drew the end token (allowEnd)
  async step() {
    const b = this.bundle, L = this.L, n = this.steps;
    const uniforms = Array.from({ length: L }, () => this.rng.random());
    const ids = this.int64(Array.from({ length: this.B * L }, (_, i) => this.last[i % L]), [this.B, 1, L]);
    const position = this.int64([n], [1]);
    const past = this.int64(this.positions, [this.positions.length]);
    const outputs = [];
    for (let level = 0; level < L; level++)
      outputs.push(await b.runLevel(level, [this.prompt, this.uncond, ids, position, past, ...this.caches[level]]));
    const endAllowed = this.allowEnd && n > 0;
    const row = outputs.map(([logits], level) => {
      const K = logits.dims[1], data = logits.data;
      return chooseToken(data.subarray(0, K), this.B === 2 ? data.subarray(K, 2 * K) : null,
        uniforms[level], this.sampling, level === 0 && !endAllowed ? b.endToken : null);
    });
    if (row[0] === b.endToken) return null;
    const presents = outputs.map(([, ...p]) => p);
    if (this.window !== null && this.positions.length === 1 + this.window) {
      const slot = this.oldest;  // the new slot overwrites the oldest step's in place
      presents.forEach((levelPresents, level) => levelPresents.forEach((present, k) => {
        const held = this.caches[level][k];
        const [bh, h, p, d] = held.dims;
        for (let i = 0; i < bh * h; i++)
          held.data.set(present.data.subarray((i * (p + 1) + p) * d, (i * (p + 1) + p + 1) * d),
            (i * p + slot) * d);
      }));
      this.positions[slot] = n;
      this.slotTokens[slot] = this.last;
      this.oldest = (slot % this.window) + 1;
    } else {
      this.caches = presents;
      this.positions.push(n);
      this.slotTokens.push(this.last);
    }
    this.last = row;
    this.steps = n + 1;
    return row;
  }

  // a new prompt from the next step on: every held slot recomputed under it in one call of
  // each level (the prefix and the held steps with their tokens)
  async setPrompt(embedding) {
    this.prompt = this.batch(embedding);
    if (this.positions.length) await this.prefill();
  }

  async prefill() {
    const P = this.positions.length, L = this.L;
    const ids = this.int64(Array.from({ length: this.B }, () => this.slotTokens.flat()).flat(), [this.B, P, L]);
    const positions = this.int64(this.positions, [P]);
    const none = this.int64([], [0]);
    for (let level = 0; level < L; level++) {
      const [, ...presents] = await this.bundle.runLevel(level,
        [this.prompt, this.uncond, ids, positions, none, ...this.emptyCache(level)]);
      this.caches[level] = presents;
    }
  }
}

// -- the streaming decoder: mogo.stream_decoder's window arithmetic (spec §8) ---------------
export class StreamingDecoder {
  constructor(bundle, every = 8) {
    const d = bundle.manifest.vq.decoder;
    this.bundle = bundle; this.left = d.left_context; this.lookahead = d.lookahead;
    this.every = every; this.tokens = []; this.start = 0; this.pushed = 0; this.emitted = 0;
  }

  // rows (n x L) in; the features (Float64Array, frames x D) that became final out
  async push(rows) {
    this.tokens.push(...rows);
    this.pushed += rows.length;
    const ready = this.pushed - this.lookahead;
    if (ready <= this.emitted || (this.emitted && ready - this.emitted < this.every))
      return new Float64Array(0);
    return this.take(ready, this.tokens);
  }

  // the stream's end: `context` rows after it are the right context of its last frames
  async flush(context) {
    return this.take(this.pushed, [...this.tokens, ...context]);
  }

  async take(ready, window) {
    const D = this.bundle.mean.length;
    const features = await this.bundle.decodeFeatures(window);
    const perToken = features.length / D / window.length;
    const first = (this.emitted - this.start) * perToken * D;
    const frames = features.slice(first, first + (ready - this.emitted) * perToken * D);
    this.emitted = ready;
    const keepFrom = Math.max(0, ready - this.left);
    this.tokens = this.tokens.slice(keepFrom - this.start);
    this.start = keepFrom;
    return frames;
  }
}

// -- re-anchoring: mogo.anchoring, its words from words.json (spec §8) --------------------
const LETTER_FIXES = { "ß": "ss", "æ": "ae", "œ": "oe", "ø": "o", "ł": "l", "đ": "d",
                       "\u2019": "'", "\u2018": "'", "\u2013": "-", "\u2014": "-" };

export function plainWords(text) {
  // lowercase ASCII words: accents stripped, other scripts dropped, digits kept (mogo.align)
  const fixed = [...text.toLowerCase()].map((c) => LETTER_FIXES[c] ?? c).join("");
  const ascii = [...fixed.normalize("NFKD")].filter((c) => c.charCodeAt(0) < 128).join("");
  return ascii.replaceAll("'", "").split(/[^a-z0-9]+/).filter(Boolean);
}

function primitiveOf(words, w) {
  let primitive = words.map((x) => w.verbs[x]).find((p) => p) ?? null;
  if (words.includes("jumping") && (words.includes("jacks") || words.includes("jack")))
    primitive = "jumping_jacks";
  return primitive ?? words.map((x) => w.nouns[x]).find((p) => p) ?? null;
}

// prompts that ask for something that ends: a one-off action, a count, a sequence
export function settles(text, w) {
  const words = plainWords(text);
  return words.some((x) => w.counts.includes(x) || /^[0-9]+$/.test(x))
    || w.one_off.includes(primitiveOf(words, w));
}

// -- an endless stream: tokens in, final frames out (spec §8) ------------------------------
export class MotionStream {
  // options: window (default the bundle's), words (words.json: re-anchored; null: not),
  // embed (text -> embedding, for the hold prompt), plantFeet (default true)
  constructor(bundle, text, embedding, seed, sampling, options = {}) {
    this.bundle = bundle;
    this.tokens = new TokenStream(bundle, embedding, seed, sampling,
      options.window === undefined ? bundle.manifest.defaults.window : options.window);
    this.words = options.words ?? null;
    this.embed = options.embed;
    this.decoder = new StreamingDecoder(bundle);
    this.joints = new JointStream(bundle.mean.length, bundle.numJoints);
    this.feet = options.plantFeet === false ? null : new FootPlanter(bundle.manifest);
    this.rows = [];
    this.holding = false;
    if (this.words) this.kind(text);
  }

  kind(text) {
    this.oneOff = settles(text, this.words);
    this.still = primitiveOf(plainWords(text), this.words) === this.words.still;
    this.tokens.allowEnd = !this.still;
  }

  // one token step; the joints (frames x J x 3, Float32Array) that became final, maybe none
  async step() {
    const a = this.words?.anchoring;
    let row = await this.tokens.step();
    if (row === null) {  // the model ended its clip: a fresh one, or after a one-off the hold
      if (this.oneOff) await this.hold(); else this.tokens.restart();
      row = await this.tokens.step();
    }
    this.rows.push(row);
    if (a && this.oneOff) {
      if (this.tokens.steps >= a.max_one_off) await this.hold();
    } else if (a && this.tokens.steps >= a.span) {
      await this.tokens.continueFrom(this.rows.slice(-(this.still ? a.still_keep : a.keep)));
    }
    const features = await this.decoder.push([row]);
    const n = features.length / this.bundle.mean.length, joints = this.joints.push(features, n);
    return this.feet ? this.feet.push(features, joints, n) : joints;
  }

  async hold() {
    const prompt = this.words.anchoring.hold_prompt;
    this.tokens.prompt = this.tokens.batch(await this.embed(prompt));
    this.holding = true;
    this.kind(prompt);
    this.tokens.restart();
  }

  // from the next step on (exact: every held cache slot recomputed under the new prompt)
  async setPrompt(text, embedding) {
    await this.tokens.setPrompt(embedding);
    if (!this.words) return;
    this.holding = false;
    this.kind(text);
    if (this.rows.length)
      await this.tokens.continueFrom(this.rows.slice(-this.words.anchoring.switch_keep));
  }
}

// -- the conformance rule (mogo.export.onnx.conformance.compare_tokens) --------------------
export function compareTokens(c, rows, tolerances) {
  for (let n = 0; n < c.tokens.length; n++)
    for (let l = 0; l < c.tokens[n].length; l++)
      if (rows[n][l] !== c.tokens[n][l]) {
        const margin = c.margins[n][l], gap = c.gaps[n][l];
        if (gap < tolerances.tie_logit || margin < tolerances.tie_mass) return { agreed: n, problem: null };
        return { agreed: n, problem: `${c.name}: step ${n} level ${l}: token ${rows[n][l]}, expected ${c.tokens[n][l]} (margin ${margin}, gap ${gap}: no tie)` };
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
    const schedule = c.schedule;
    const stream = new TokenStream(bundle, Float32Array.from(schedule[0].prompt_embedding),
      c.seed, c.sampling, c.window);
    const rows = [];
    for (const [k, entry] of schedule.entries()) {
      if (k) await stream.setPrompt(Float32Array.from(entry.prompt_embedding));
      for (let n = 0; n < entry.steps; n++) rows.push(await stream.step());
    }
    while (rows.length < c.steps) rows.push(await stream.step());
    const seconds = (performance.now() - start) / 1000;
    const { agreed, problem } = compareTokens(c, rows, vectors.tolerances);
    if (problem) problems.push(problem);
    let jointsDifference = null;
    if (agreed === c.steps) {
      jointsDifference = 0;
      for (const [key, plant] of [["joints", false], ["joints_planted", true]]) {
        if (!c[key]) continue;
        const joints = await bundle.decode(rows, c.frames, plant), expected = c[key].flat(2);
        let largest = 0;
        expected.forEach((v, i) => { largest = Math.max(largest, Math.abs(joints[i] - v)); });
        if (!(largest < vectors.tolerances.joints_m))
          problems.push(`${c.name}: ${key} differ by ${largest} m`);
        jointsDifference = Math.max(jointsDifference, largest);
      }
    }
    report.cases.push({ name: c.name, steps: c.steps, agreed, jointsDifference, tokenSeconds: seconds });
    log(`${c.name}: ${agreed}/${c.steps} steps agree, joints ${jointsDifference}, ${seconds.toFixed(2)} s`);
  }
  return report;
}
