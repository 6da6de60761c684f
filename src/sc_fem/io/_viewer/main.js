// sc_fem web viewer: plays the modes baked into a glTF (morph targets) in real time.
// Bundled with three.js by esbuild at install time (make viewer) into viewer.js; sc-fem view
// inlines that bundle, the glb (base64) and a JSON config into one HTML page: no network needed.
//
// Physics (the same as sc_fem.ModalPlayer): each modal coordinate q_k obeys
// q'' + 2 zeta w q' + w^2 q = 0 between strikes and is advanced by its exact solution; a strike
// (impulse J, N s, on vertex v) adds phi_k(v) . J to each modal velocity. Morph target k holds
// d_k = s_k phi_k / scale (model units), so phi_k(v) = d_k(v) scale / s_k, and the mode weight
// is q_k / s_k (plus the slider's static offset).
//
// Quantized pages (KHR_mesh_quantization, sc_fem.io.quantize): morph target k holds d_k on its
// own 16-bit range, so the morph influence is the mode weight times cfg.weight_factors[k], and
// d_k(v) = nodeScale * weight_factors[k] * (normalized value). The glb arrives packed
// (sc_fem.io.viewer.pack_glb): zlib, then per 16-bit vertex stream zigzag residuals from a parent
// vertex in byte planes; unpack() undoes it exactly before GLTFLoader reads the glb.
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { unzlibSync } from 'three/examples/jsm/libs/fflate.module.js';

const cfg = JSON.parse(document.getElementById('sc-config').textContent);
const state = { ready: false, strikes: 0, time: 0, errors: [], lastImpulse: null };
window.scViewer = state;

function decodeBase64(text) {
  const bin = atob(text.trim());
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

// the glb of a payload packed by sc_fem.io.viewer.pack_glb (spec: cfg.payload)
function unpack(bytes, spec) {
  const data = unzlibSync(bytes, { out: new Uint8Array(spec.bytes) });
  const n = spec.vertices, L = spec.glb_bytes;
  const parent = new Int32Array(n);
  for (let i = 0; i < n; i++) {
    const gap = (data[L + i] | (data[L + n + i] << 8) | (data[L + 2 * n + i] << 16) | (data[L + 3 * n + i] << 24)) >>> 0;
    parent[i] = gap ? i - gap : -1;
  }
  const planes = new Uint8Array(8 * n), vals = new Int32Array(4 * n);
  for (const off of spec.streams) {
    planes.set(data.subarray(off, off + 8 * n));
    for (let i = 0; i < n; i++) {
      const p = parent[i];
      for (let c = 0; c < 4; c++) {
        const z = planes[2 * c * n + i] | (planes[(2 * c + 1) * n + i] << 8);
        const v = ((((p >= 0 ? vals[4 * p + c] : 0) + ((z >>> 1) ^ -(z & 1))) << 16) >> 16);    // int16, wrapped
        vals[4 * i + c] = v;
        data[off + 8 * i + 2 * c] = v & 255;
        data[off + 8 * i + 2 * c + 1] = (v >> 8) & 255;
      }
    }
  }
  return data.slice(0, L);
}

function adler32(bytes) {
  let a = 1, b = 0;
  for (let i = 0; i < bytes.length; i++) { a = (a + bytes[i]) % 65521; b = (b + a) % 65521; }
  return ((b << 16) | a) >>> 0;
}

// exact state transition of a damped oscillator over dt: [q, v] <- [[a, b], [c, d]] [q, v]
function transition(w, z, dt) {
  if (w === 0) return [1, dt, 0, 1];
  if (z < 1) {
    const wd = w * Math.sqrt(1 - z * z), e = Math.exp(-z * w * dt);
    const cs = Math.cos(wd * dt), sn = Math.sin(wd * dt);
    return [e * (cs + (z * w / wd) * sn), e * sn / wd, -e * (w * w / wd) * sn, e * (cs - (z * w / wd) * sn)];
  }
  if (z === 1) {
    const e = Math.exp(-w * dt);
    return [e * (1 + w * dt), e * dt, -e * w * w * dt, e * (1 - w * dt)];
  }
  const r = w * Math.sqrt(z * z - 1), r1 = -z * w + r, r2 = -z * w - r;
  const e1 = Math.exp(r1 * dt), e2 = Math.exp(r2 * dt), den = r1 - r2;
  return [(r1 * e2 - r2 * e1) / den, (e1 - e2) / den, r1 * r2 * (e2 - e1) / den, (r1 * e1 - r2 * e2) / den];
}

const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
const view = document.getElementById('view');
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xffffff);
scene.add(new THREE.HemisphereLight(0xffffff, 0x8899aa, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
scene.add(sun);
const camera = new THREE.PerspectiveCamera(35, 1, 0.001, 1e6);
const controls = new OrbitControls(camera, renderer.domElement);
const clock = new THREE.Clock();

function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);

let mesh = null, targets = [], q = [], v = [], offsets = [], nodeScale = 1;
const freqs = cfg.frequencies_hz, zetas = cfg.damping_ratios, scales = cfg.mode_scales;
const factors = cfg.weight_factors || freqs.map(() => 1);
const omegas = freqs.map((f) => 2 * Math.PI * f);
const K = freqs.length;

function buildUI() {
  const table = document.getElementById('modes');
  freqs.forEach((f, k) => {
    const row = document.createElement('tr');
    row.innerHTML = `<td>${k}</td><td>${f.toPrecision(4)}</td><td>${(100 * zetas[k]).toPrecision(2)} %</td>` +
      `<td><input type="range" min="-1" max="1" step="0.01" value="0" id="w${k}" aria-label="mode ${k} weight"></td>`;
    table.appendChild(row);
    row.querySelector('input').addEventListener('input', (e) => { offsets[k] = parseFloat(e.target.value); });
  });
  document.getElementById('reset').addEventListener('click', () => {
    q.fill(0); v.fill(0); offsets.fill(0);
    document.querySelectorAll('#modes input').forEach((el) => { el.value = 0; });
  });
  const slow = document.getElementById('slow');
  slow.addEventListener('change', () => { document.getElementById('scale-note').textContent = timeNote(); });
  document.getElementById('scale-note').textContent = timeNote();
}

function timeScale() { return parseFloat(document.getElementById('slow').value); }
function timeNote() {
  const s = timeScale();
  return s === 1 ? 'real time' : `slow motion: 1 s on screen = ${s} s simulated`;
}

// strike: an impulse into the surface at the vertex nearest the click, scaled so that the
// largest modal response is about weight 1 (the size is printed; the shape of the response is exact)
function strike(vertex, normal) {
  const pos = mesh.geometry.attributes.position;
  let peak = 0;
  const dv = new Array(K).fill(0);
  for (let k = 0; k < K; k++) {
    const d = targets[k], unit = nodeScale * factors[k];         // model units per stored (normalized) value
    const phi = [d.getX(vertex), d.getY(vertex), d.getZ(vertex)].map((x) => x * unit * cfg.scale_m_per_unit / (scales[k] || 1));
    dv[k] = -(phi[0] * normal.x + phi[1] * normal.y + phi[2] * normal.z);          // per N s, pushing in
    const amp = omegas[k] > 0 ? Math.abs(dv[k]) / (omegas[k] * (scales[k] || 1)) : 0;
    peak = Math.max(peak, amp);
  }
  const J = peak > 0 ? 1 / peak : 0;
  for (let k = 0; k < K; k++) v[k] += J * dv[k];
  state.strikes += 1;
  state.lastImpulse = { vertex, J };
  document.getElementById('impulse').textContent =
    `impulse ${J.toPrecision(3)} N s on vertex ${vertex} (${pos.count} vertices)`;
}

const raycaster = new THREE.Raycaster();
let down = null;                         // a click strikes; a drag orbits
renderer.domElement.addEventListener('pointerdown', (ev) => { down = [ev.clientX, ev.clientY]; });
renderer.domElement.addEventListener('pointerup', (ev) => {
  const moved = down ? Math.hypot(ev.clientX - down[0], ev.clientY - down[1]) : Infinity;
  down = null;
  if (!mesh || ev.button !== 0 || moved > 4) return;
  const rect = renderer.domElement.getBoundingClientRect();
  const p = new THREE.Vector2(((ev.clientX - rect.left) / rect.width) * 2 - 1, -((ev.clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(p, camera);
  const hit = raycaster.intersectObject(mesh, false)[0];
  if (!hit || !hit.face) return;
  const pos = mesh.geometry.attributes.position;
  let best = hit.face.a, bestD = Infinity;
  for (const i of [hit.face.a, hit.face.b, hit.face.c]) {
    const d = new THREE.Vector3().fromBufferAttribute(pos, i).applyMatrix4(mesh.matrixWorld).distanceTo(hit.point);
    if (d < bestD) { bestD = d; best = i; }
  }
  strike(best, hit.face.normal.clone().transformDirection(mesh.matrixWorld));
});

function animate() {
  requestAnimationFrame(animate);
  const dt = Math.min(clock.getDelta(), 0.1) * timeScale();
  if (mesh) {
    for (let k = 0; k < K; k++) {
      const [a, b, c, d] = transition(omegas[k], zetas[k], dt);
      const qk = a * q[k] + b * v[k];
      v[k] = c * q[k] + d * v[k];
      q[k] = qk;
      mesh.morphTargetInfluences[k] = factors[k] * (offsets[k] + (scales[k] ? q[k] / scales[k] : 0));
    }
    state.time += dt;
    document.getElementById('clock').textContent = `t = ${state.time.toFixed(3)} s simulated`;
  }
  controls.update();
  renderer.render(scene, camera);
}

let glb;
try {
  glb = unpack(decodeBase64(document.getElementById('sc-glb').textContent), cfg.payload);
  state.glb = { bytes: glb.length, adler32: adler32(glb) };
} catch (err) { state.errors.push(`cannot unpack the model: ${err}`); console.error(err); }
if (glb) new GLTFLoader().parse(glb.buffer, '', (gltf) => {
  gltf.scene.traverse((o) => { if (o.isMesh && !mesh) mesh = o; });
  if (!mesh) { state.errors.push('no mesh in the glTF'); return; }
  mesh.material = new THREE.MeshStandardMaterial({ color: 0xd9822b, roughness: 0.7, metalness: 0.0,
    side: THREE.DoubleSide, flatShading: true });
  targets = mesh.geometry.morphAttributes.position;
  q = new Array(K).fill(0); v = new Array(K).fill(0); offsets = new Array(K).fill(0);
  scene.add(gltf.scene);
  gltf.scene.updateMatrixWorld(true);
  nodeScale = mesh.matrixWorld.getMaxScaleOnAxis();           // the quantized positions' scale (1 for float)
  // frame the model: up axis drawn upward, a three-quarter view from above; the rest shape's box
  // (three.js' own box would take every quantized target at influence 1) widened by the amplitude
  const box = new THREE.Box3().setFromObject(gltf.scene, true);
  box.expandByScalar((cfg.amplitude || 0) * box.getSize(new THREE.Vector3()).length());
  const size = box.getSize(new THREE.Vector3()), centre = box.getCenter(new THREE.Vector3());
  const up = new THREE.Vector3(...cfg.up_vector);
  const axes = [new THREE.Vector3(1, 0, 0), new THREE.Vector3(0, 1, 0), new THREE.Vector3(0, 0, 1)];
  const a = cfg.up_vector.indexOf(1);
  const dir = axes[(a + 1) % 3].clone().multiplyScalar(1.0).add(axes[(a + 2) % 3].clone().multiplyScalar(-1.3))
    .add(up.clone().multiplyScalar(0.9)).normalize();
  camera.up.copy(up);
  const dist = 1.9 * size.length() / (2 * Math.tan((camera.fov * Math.PI) / 360));
  camera.position.copy(centre).addScaledVector(dir, dist);
  camera.near = dist / 1000; camera.far = dist * 100; camera.updateProjectionMatrix();
  controls.target.copy(centre);
  sun.position.copy(centre).addScaledVector(dir, dist).addScaledVector(up, dist);
  buildUI();
  resize();
  state.ready = true;
}, (err) => { state.errors.push(String(err)); console.error(err); });

animate();
