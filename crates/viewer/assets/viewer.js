/* transsplat in-browser Gaussian splatting viewer.
 *
 * Plain ES2020, no modules, no network. The page inlines this file after one or
 * more <div class="ts-viewer"> containers, each holding a META JSON script
 * (class "ts-meta") and base64 blobs (class "ts-blob", data-blob="<index>").
 * See README.md beside this file for the data format, the controls, the JS API
 * and the rendering conventions (which follow the project's CPU rasterizer).
 */
'use strict';

/** Builds a viewer inside `root` and returns its API (also stored as root.tsViewer). */
function transsplatViewer(root) {
  return transsplatViewer.lib.create(root);
}

transsplatViewer.lib = (function () {
  const SH_C0 = 0.28209479177387814;
  const SH_C1 = 0.4886025;
  const NEAR = 0.01;
  const TEX_SHIFT = 11;
  const TEX_W = 1 << TEX_SHIFT; // data textures are TEX_W texels wide, one texel per Gaussian
  // Quads per draw call: 4 vertices each with Uint16 indices, whose largest value 65535
  // is the primitive-restart index (always on in WebGL2) and must not be used.
  const BATCH = 16383;
  const WEBGL2_MESSAGE =
    'This viewer needs WebGL2, which this browser does not provide (or it is turned off). ' +
    'Open the page in a current Chrome, Edge, Firefox or Safari with hardware acceleration enabled.';
  const ROLE_COLOURS = { edit: '#ff9f1c', test: '#2ec4f0', train: '#c8c8c8' };
  const OTHER_ROLE_COLOUR = '#8ee08e';
  // Label colours: class 0 is a neutral grey, 1 a strong orange-red, then distinct hues.
  const PALETTE = [
    [0.42, 0.42, 0.42], [1.0, 0.3, 0.08], [0.12, 0.55, 1.0], [0.2, 0.82, 0.3],
    [1.0, 0.86, 0.1], [0.72, 0.3, 0.95], [0.1, 0.9, 0.85], [1.0, 0.45, 0.75],
    [0.6, 0.38, 0.18], [0.6, 0.78, 0.1], [0.3, 0.3, 0.85], [0.95, 0.95, 0.95],
    [0.98, 0.62, 0.42], [0.45, 0.98, 0.65], [0.8, 0.08, 0.3], [0.55, 0.8, 1.0],
  ];
  // Scalar heat map stops (value, r, g, b), piecewise linear.
  const HEAT = [
    [0.0, 0.03, 0.02, 0.16], [0.25, 0.38, 0.06, 0.55], [0.5, 0.85, 0.2, 0.32],
    [0.75, 0.99, 0.6, 0.1], [1.0, 1.0, 1.0, 0.78],
  ];

  /* ------------------------------------------------------------------ */
  /* small helpers                                                      */
  /* ------------------------------------------------------------------ */

  function el(tag, cls, parent, text) {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined && text !== null) e.textContent = String(text);
    if (parent) parent.appendChild(e);
    return e;
  }

  function fmtInt(n) {
    return Number(n).toLocaleString('en-US');
  }

  function isNum(v) {
    return typeof v === 'number' && Number.isFinite(v);
  }

  function isCount(v) {
    return Number.isInteger(v) && v >= 0;
  }

  function nextTask() {
    return new Promise(function (res) { setTimeout(res, 0); });
  }

  /** Base64 (standard or URL-safe, whitespace allowed) to bytes. */
  function decodeBase64(str, what) {
    const table = new Uint8Array(256).fill(255);
    const abc = 'ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/';
    for (let i = 0; i < 64; i++) table[abc.charCodeAt(i)] = i;
    table[45] = 62; // '-'
    table[95] = 63; // '_'
    const n = str.length;
    const out = new Uint8Array(Math.floor(n * 3 / 4) + 3);
    let acc = 0;
    let bits = 0;
    let o = 0;
    for (let i = 0; i < n; i++) {
      const c = str.charCodeAt(i);
      const v = c < 256 ? table[c] : 255;
      if (v === 255) {
        if (c === 61) break; // '=' padding: the end
        if (c === 32 || c === 10 || c === 13 || c === 9 || c === 12) continue;
        throw new Error(what + ': invalid base64 character at offset ' + i);
      }
      acc = (acc << 6) | v;
      bits += 6;
      if (bits >= 8) {
        bits -= 8;
        out[o++] = (acc >>> bits) & 255;
      }
    }
    return out.subarray(0, o);
  }

  /* ------------------------------------------------------------------ */
  /* 3x3 / vector math (row-major arrays of 9)                          */
  /* ------------------------------------------------------------------ */

  function mat3Mul(a, b) {
    const r = new Array(9);
    for (let i = 0; i < 3; i++) {
      for (let j = 0; j < 3; j++) {
        r[i * 3 + j] = a[i * 3] * b[j] + a[i * 3 + 1] * b[3 + j] + a[i * 3 + 2] * b[6 + j];
      }
    }
    return r;
  }

  function mat3T(a) {
    return [a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]];
  }

  function mat3Vec(a, v) {
    return [
      a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
      a[3] * v[0] + a[4] * v[1] + a[5] * v[2],
      a[6] * v[0] + a[7] * v[1] + a[8] * v[2],
    ];
  }

  function mat3TVec(a, v) {
    return [
      a[0] * v[0] + a[3] * v[1] + a[6] * v[2],
      a[1] * v[0] + a[4] * v[1] + a[7] * v[2],
      a[2] * v[0] + a[5] * v[1] + a[8] * v[2],
    ];
  }

  function vAdd(a, b) { return [a[0] + b[0], a[1] + b[1], a[2] + b[2]]; }
  function vSub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function vScale(a, s) { return [a[0] * s, a[1] * s, a[2] * s]; }
  function vLen(a) { return Math.hypot(a[0], a[1], a[2]); }
  function vNorm(a) { const l = vLen(a) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }

  /** Rotation by `angle` about the unit `axis` (row-major). */
  function axisAngle(axis, angle) {
    const [x, y, z] = vNorm(axis);
    const c = Math.cos(angle);
    const s = Math.sin(angle);
    const k = 1 - c;
    return [
      c + x * x * k, x * y * k - z * s, x * z * k + y * s,
      y * x * k + z * s, c + y * y * k, y * z * k - x * s,
      z * x * k - y * s, z * y * k + x * s, c + z * z * k,
    ];
  }

  /** Re-orthonormalises a rotation (rows) that has drifted after many updates. */
  function orthonormalise(R) {
    const r0 = vNorm([R[0], R[1], R[2]]);
    let r1 = [R[3], R[4], R[5]];
    const d = r0[0] * r1[0] + r0[1] * r1[1] + r0[2] * r1[2];
    r1 = vNorm(vSub(r1, vScale(r0, d)));
    const r2 = [
      r0[1] * r1[2] - r0[2] * r1[1],
      r0[2] * r1[0] - r0[0] * r1[2],
      r0[0] * r1[1] - r0[1] * r1[0],
    ];
    return [r0[0], r0[1], r0[2], r1[0], r1[1], r1[2], r2[0], r2[1], r2[2]];
  }

  /* ------------------------------------------------------------------ */
  /* PLY parsing and Gaussian decoding                                  */
  /* ------------------------------------------------------------------ */

  const PLY_TYPES = {
    char: 'i8', int8: 'i8', uchar: 'u8', uint8: 'u8', short: 'i16', int16: 'i16',
    ushort: 'u16', uint16: 'u16', int: 'i32', int32: 'i32', uint: 'u32', uint32: 'u32',
    float: 'f32', float32: 'f32', double: 'f64', float64: 'f64',
  };
  const TYPE_SIZE = { i8: 1, u8: 1, i16: 2, u16: 2, i32: 4, u32: 4, f32: 4, f64: 8 };

  function parsePly(bytes, what) {
    // Locate "end_header" at the start of a line, then the newline after it.
    const pat = [101, 110, 100, 95, 104, 101, 97, 100, 101, 114]; // "end_header"
    const lim = Math.min(bytes.length - pat.length, 1 << 20);
    let at = -1;
    for (let i = 0; i <= lim; i++) {
      if (bytes[i] === 101 && (i === 0 || bytes[i - 1] === 10)) {
        let ok = true;
        for (let k = 1; k < pat.length; k++) {
          if (bytes[i + k] !== pat[k]) { ok = false; break; }
        }
        if (ok) { at = i; break; }
      }
    }
    if (bytes.length < 4 || bytes[0] !== 112 || bytes[1] !== 108 || bytes[2] !== 121) {
      throw new Error(what + ': not a PLY file (it does not start with "ply")');
    }
    if (at < 0) throw new Error(what + ': PLY header has no end_header line');
    let dataStart = at + pat.length;
    while (dataStart < bytes.length && (bytes[dataStart] === 13 || bytes[dataStart] === 32)) dataStart++;
    if (bytes[dataStart] !== 10) throw new Error(what + ': malformed end_header line');
    dataStart++;
    let header = '';
    for (let i = 0; i < at; i++) header += String.fromCharCode(bytes[i]);
    const elements = [];
    let format = null;
    let cur = null;
    const lines = header.split(/\r?\n/);
    for (let li = 1; li < lines.length; li++) {
      const tok = lines[li].trim().split(/\s+/);
      if (!tok[0]) continue;
      if (tok[0] === 'format') {
        format = tok[1];
      } else if (tok[0] === 'element') {
        const count = Number(tok[2]);
        if (!tok[1] || !isCount(count)) throw new Error(what + ': bad PLY element line "' + lines[li] + '"');
        cur = { name: tok[1], count: count, props: [], rowSize: 0, offset: 0 };
        elements.push(cur);
      } else if (tok[0] === 'property') {
        if (!cur) throw new Error(what + ': PLY property before any element');
        if (tok[1] === 'list') throw new Error(what + ': PLY list properties are not supported (' + cur.name + ')');
        const type = PLY_TYPES[tok[1]];
        if (!type || !tok[2]) throw new Error(what + ': bad PLY property line "' + lines[li] + '"');
        cur.props.push({ name: tok[2], type: type, offset: cur.rowSize });
        cur.rowSize += TYPE_SIZE[type];
      }
      // comment / obj_info lines are ignored
    }
    if (format !== 'binary_little_endian') {
      throw new Error(what + ': PLY format "' + format + '" is not supported (binary_little_endian only)');
    }
    let off = dataStart;
    for (const e of elements) {
      e.offset = off;
      off += e.count * e.rowSize;
    }
    if (off > bytes.length) {
      throw new Error(what + ': PLY data is truncated (' + bytes.length + ' bytes, header says ' + off + ')');
    }
    return {
      elements: elements,
      dv: new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength),
      element: function (name) { return elements.find(function (e) { return e.name === name; }) || null; },
    };
  }

  function hasProp(elem, name) {
    return elem.props.some(function (p) { return p.name === name; });
  }

  /** One property column as `Type` (Float64Array by default); null if absent. */
  function column(ply, elem, name, Type) {
    const p = elem.props.find(function (q) { return q.name === name; });
    if (!p) return null;
    const n = elem.count;
    const out = new (Type || Float64Array)(n);
    const dv = ply.dv;
    const st = elem.rowSize;
    let o = elem.offset + p.offset;
    switch (p.type) {
      case 'u8': for (let i = 0; i < n; i++, o += st) out[i] = dv.getUint8(o); break;
      case 'i8': for (let i = 0; i < n; i++, o += st) out[i] = dv.getInt8(o); break;
      case 'u16': for (let i = 0; i < n; i++, o += st) out[i] = dv.getUint16(o, true); break;
      case 'i16': for (let i = 0; i < n; i++, o += st) out[i] = dv.getInt16(o, true); break;
      case 'u32': for (let i = 0; i < n; i++, o += st) out[i] = dv.getUint32(o, true); break;
      case 'i32': for (let i = 0; i < n; i++, o += st) out[i] = dv.getInt32(o, true); break;
      case 'f32': for (let i = 0; i < n; i++, o += st) out[i] = dv.getFloat32(o, true); break;
      default: for (let i = 0; i < n; i++, o += st) out[i] = dv.getFloat64(o, true); break;
    }
    out.plyType = p.type;
    return out;
  }

  function need(ply, elem, name, what, Type) {
    const c = column(ply, elem, name, Type);
    if (!c) throw new Error(what + ': element "' + elem.name + '" has no property "' + name + '"');
    return c;
  }

  /** Sigma = R S S^T R^T from a (w,x,y,z) quaternion and linear scales into out[o..o+6]
   * as (xx, xy, xz, yy, yz, zz). */
  function writeCov(w, x, y, z, sx, sy, sz, out, o) {
    let n = Math.sqrt(w * w + x * x + y * y + z * z);
    if (!(n > 0) || !Number.isFinite(n)) { w = 1; x = 0; y = 0; z = 0; n = 1; }
    w /= n; x /= n; y /= n; z /= n;
    const r00 = 1 - 2 * (y * y + z * z), r01 = 2 * (x * y - w * z), r02 = 2 * (x * z + w * y);
    const r10 = 2 * (x * y + w * z), r11 = 1 - 2 * (x * x + z * z), r12 = 2 * (y * z - w * x);
    const r20 = 2 * (x * z - w * y), r21 = 2 * (y * z + w * x), r22 = 1 - 2 * (x * x + y * y);
    const m00 = r00 * sx, m01 = r01 * sy, m02 = r02 * sz;
    const m10 = r10 * sx, m11 = r11 * sy, m12 = r12 * sz;
    const m20 = r20 * sx, m21 = r21 * sy, m22 = r22 * sz;
    out[o] = m00 * m00 + m01 * m01 + m02 * m02;
    out[o + 1] = m00 * m10 + m01 * m11 + m02 * m12;
    out[o + 2] = m00 * m20 + m01 * m21 + m02 * m22;
    out[o + 3] = m10 * m10 + m11 * m11 + m12 * m12;
    out[o + 4] = m10 * m20 + m11 * m21 + m12 * m22;
    out[o + 5] = m20 * m20 + m21 * m21 + m22 * m22;
  }

  /** Degree-1 SH columns (f_rest) as out[9 i + 3 ch + (0..2)], or null if none. */
  function readShDegree1(ply, elem, n, what) {
    let K = 0;
    while (hasProp(elem, 'f_rest_' + K)) K++;
    if (K === 0) return null;
    if (K % 3 !== 0) throw new Error(what + ': ' + K + ' f_rest properties is not a multiple of 3');
    const k = K / 3;
    if (k < 3) return null;
    const sh = new Float32Array(n * 9);
    for (let ch = 0; ch < 3; ch++) {
      for (let i = 0; i < 3; i++) {
        const col = column(ply, elem, 'f_rest_' + (ch * k + i));
        const bytes = col.plyType === 'u8';
        for (let g = 0; g < n; g++) {
          let v = col[g];
          if (bytes) {
            const u = v === 0 ? 0 : v === 255 ? 1 : (v + 0.5) / 256;
            v = (u - 0.5) * 8;
          }
          sh[g * 9 + ch * 3 + i] = Number.isFinite(v) ? v : 0;
        }
      }
    }
    return sh;
  }

  /** Decodes a PLY (PlayCanvas compressed, or plain INRIA 3DGS) into flat arrays:
   * pos (3n), cov (6n), col (4n: base r,g,b with SH_C0 * f_dc + 0.5 folded in, opacity),
   * sh (9n or null). */
  function decodeScene(bytes, what) {
    const ply = parsePly(bytes, what);
    const vtx = ply.element('vertex');
    if (!vtx) throw new Error(what + ': PLY has no "vertex" element');
    const n = vtx.count;
    const pos = new Float32Array(n * 3);
    const cov = new Float32Array(n * 6);
    const col = new Float32Array(n * 4);
    let sh = null;
    if (hasProp(vtx, 'packed_position')) {
      const chunk = ply.element('chunk');
      if (!chunk) throw new Error(what + ': compressed PLY has no "chunk" element');
      if (chunk.count * 256 < n) {
        throw new Error(what + ': ' + chunk.count + ' chunks cannot cover ' + n + ' Gaussians');
      }
      const pp = need(ply, vtx, 'packed_position', what, Uint32Array);
      const pr = need(ply, vtx, 'packed_rotation', what, Uint32Array);
      const ps = need(ply, vtx, 'packed_scale', what, Uint32Array);
      const pc = need(ply, vtx, 'packed_color', what, Uint32Array);
      const c = {};
      for (const nm of ['min_x', 'min_y', 'min_z', 'max_x', 'max_y', 'max_z',
        'min_scale_x', 'min_scale_y', 'min_scale_z', 'max_scale_x', 'max_scale_y', 'max_scale_z']) {
        c[nm] = need(ply, chunk, nm, what);
      }
      const colourNames = ['min_r', 'min_g', 'min_b', 'max_r', 'max_g', 'max_b'];
      const chunkColour = colourNames.every(function (nm) { return hasProp(chunk, nm); });
      if (chunkColour) for (const nm of colourNames) c[nm] = column(ply, chunk, nm);
      const SQ2 = Math.SQRT2;
      for (let i = 0; i < n; i++) {
        const ci = i >>> 8;
        const p = pp[i];
        const x = c.min_x[ci] + (c.max_x[ci] - c.min_x[ci]) * (((p >>> 21) & 2047) / 2047);
        const y = c.min_y[ci] + (c.max_y[ci] - c.min_y[ci]) * (((p >>> 11) & 1023) / 1023);
        const z = c.min_z[ci] + (c.max_z[ci] - c.min_z[ci]) * ((p & 2047) / 2047);
        const s = ps[i];
        const lx = c.min_scale_x[ci] + (c.max_scale_x[ci] - c.min_scale_x[ci]) * (((s >>> 21) & 2047) / 2047);
        const ly = c.min_scale_y[ci] + (c.max_scale_y[ci] - c.min_scale_y[ci]) * (((s >>> 11) & 1023) / 1023);
        const lz = c.min_scale_z[ci] + (c.max_scale_z[ci] - c.min_scale_z[ci]) * ((s & 2047) / 2047);
        const r = pr[i];
        const a = (((r >>> 20) & 1023) / 1023 - 0.5) * SQ2;
        const b = (((r >>> 10) & 1023) / 1023 - 0.5) * SQ2;
        const cc = ((r & 1023) / 1023 - 0.5) * SQ2;
        const m = Math.sqrt(Math.max(0, 1 - a * a - b * b - cc * cc));
        let qw, qx, qy, qz;
        switch (r >>> 30) {
          case 0: qw = m; qx = a; qy = b; qz = cc; break;
          case 1: qw = a; qx = m; qy = b; qz = cc; break;
          case 2: qw = a; qx = b; qy = m; qz = cc; break;
          default: qw = a; qx = b; qy = cc; qz = m; break;
        }
        const k = pc[i];
        let cr = ((k >>> 24) & 255) / 255;
        let cg = ((k >>> 16) & 255) / 255;
        let cb = ((k >>> 8) & 255) / 255;
        if (chunkColour) {
          cr = c.min_r[ci] + (c.max_r[ci] - c.min_r[ci]) * cr;
          cg = c.min_g[ci] + (c.max_g[ci] - c.min_g[ci]) * cg;
          cb = c.min_b[ci] + (c.max_b[ci] - c.min_b[ci]) * cb;
        }
        store(i, x, y, z, Math.exp(lx), Math.exp(ly), Math.exp(lz), qw, qx, qy, qz, cr, cg, cb, (k & 255) / 255);
      }
      const shEl = ply.element('sh');
      if (shEl) {
        if (shEl.count !== n) throw new Error(what + ': "sh" has ' + shEl.count + ' rows for ' + n + ' Gaussians');
        sh = readShDegree1(ply, shEl, n, what);
      }
    } else if (hasProp(vtx, 'x')) {
      const X = need(ply, vtx, 'x', what), Y = need(ply, vtx, 'y', what), Z = need(ply, vtx, 'z', what);
      const d0 = need(ply, vtx, 'f_dc_0', what), d1 = need(ply, vtx, 'f_dc_1', what), d2 = need(ply, vtx, 'f_dc_2', what);
      const op = need(ply, vtx, 'opacity', what);
      const s0 = need(ply, vtx, 'scale_0', what), s1 = need(ply, vtx, 'scale_1', what), s2 = need(ply, vtx, 'scale_2', what);
      const r0 = need(ply, vtx, 'rot_0', what), r1 = need(ply, vtx, 'rot_1', what);
      const r2 = need(ply, vtx, 'rot_2', what), r3 = need(ply, vtx, 'rot_3', what);
      for (let i = 0; i < n; i++) {
        store(i, X[i], Y[i], Z[i], Math.exp(s0[i]), Math.exp(s1[i]), Math.exp(s2[i]),
          r0[i], r1[i], r2[i], r3[i], SH_C0 * d0[i] + 0.5, SH_C0 * d1[i] + 0.5, SH_C0 * d2[i] + 0.5,
          1 / (1 + Math.exp(-op[i])));
      }
      sh = readShDegree1(ply, vtx, n, what);
    } else {
      throw new Error(what + ': the vertex element has neither packed_position nor x/y/z');
    }

    function store(i, x, y, z, sx, sy, sz, qw, qx, qy, qz, cr, cg, cb, o) {
      const finite = Number.isFinite(x + y + z + sx + sy + sz + qw + qx + qy + qz + cr + cg + cb + o);
      if (!finite) { x = y = z = 0; sx = sy = sz = 1e-6; qw = 1; qx = qy = qz = 0; cr = cg = cb = 0; o = 0; }
      pos[i * 3] = x; pos[i * 3 + 1] = y; pos[i * 3 + 2] = z;
      writeCov(qw, qx, qy, qz, sx, sy, sz, cov, i * 6);
      col[i * 4] = cr; col[i * 4 + 1] = cg; col[i * 4 + 2] = cb; col[i * 4 + 3] = o;
    }
    return { n: n, pos: pos, cov: cov, col: col, sh: sh };
  }

  /* ------------------------------------------------------------------ */
  /* depth sorting (runs in a Web Worker made from a Blob URL)          */
  /* ------------------------------------------------------------------ */

  /** Self-contained sorter (no outer references: its source is copied into the worker).
   * sort(row) orders the Gaussians with view depth z = row . (x, y, z, 1) > NEAR back to
   * front: exact LSD radix sort (2 x 16 bits) of the float32 depth bits, stable by index,
   * so the reverse of the order is the reference's front-to-back (depth, index) order. */
  function tsSortCore(texW) {
    let pos = null;
    let n = 0;
    let keyBuf = null, keys = null, depth = null, idx = null, keys2 = null, idx2 = null;
    const hist = new Uint32Array(65536 * 2);
    return {
      init: function (positions) {
        pos = positions;
        n = positions.length / 3;
        keyBuf = new ArrayBuffer(n * 4);
        keys = new Uint32Array(keyBuf);
        depth = new Float32Array(keyBuf);
        idx = new Uint32Array(n);
        keys2 = new Uint32Array(n);
        idx2 = new Uint32Array(n);
      },
      sort: function (row, near) {
        const t0 = performance.now();
        const r0 = row[0], r1 = row[1], r2 = row[2], r3 = row[3];
        let m = 0;
        for (let i = 0, o = 0; i < n; i++, o += 3) {
          const z = r0 * pos[o] + r1 * pos[o + 1] + r2 * pos[o + 2] + r3;
          if (z > near) { depth[m] = z; idx[m] = i; m++; }
        }
        // Both 16-bit histograms in one pass (keys are positive float bits: monotonic).
        hist.fill(0);
        for (let j = 0; j < m; j++) {
          const k = keys[j];
          hist[k & 65535]++;
          hist[65536 + (k >>> 16)]++;
        }
        let sLo = 0, sHi = 0;
        for (let b = 0; b < 65536; b++) {
          const cl = hist[b]; hist[b] = sLo; sLo += cl;
          const ch = hist[65536 + b]; hist[65536 + b] = sHi; sHi += ch;
        }
        for (let j = 0; j < m; j++) {
          const k = keys[j];
          const d = hist[k & 65535]++;
          keys2[d] = k; idx2[d] = idx[j];
        }
        // Padded to whole rows of the order texture (TEX_W wide, a power of two).
        const order = new Uint32Array(Math.ceil(m / texW) * texW);
        const last = m - 1;
        for (let j = 0; j < m; j++) {
          const d = hist[65536 + (keys2[j] >>> 16)]++;
          order[last - d] = idx2[j];
        }
        return { order: order, count: m, ms: performance.now() - t0 };
      },
    };
  }

  function tsWorkerMain() {
    /* global tsSortCore */
    let core = null;
    self.onmessage = function (e) {
      const msg = e.data;
      if (msg.type === 'init') {
        core = tsSortCore(msg.texW);
        core.init(msg.positions);
      } else if (msg.type === 'sort') {
        const r = core.sort(msg.row, msg.near);
        self.postMessage({ id: msg.id, order: r.order, count: r.count, ms: r.ms }, [r.order.buffer]);
      }
    };
  }

  let workerUrl = null;
  function workerSource() {
    return 'var tsSortCore = ' + tsSortCore.toString() + ';\n(' + tsWorkerMain.toString() + ')();\n';
  }

  /** Sorts one geometry, in a worker when possible (else on the main thread, later). */
  function Sorter(positions, onResult) {
    this.onResult = onResult;
    this.busy = false;
    this.nextId = 1;
    this.worker = null;
    this.core = null;
    try {
      if (!workerUrl) workerUrl = URL.createObjectURL(new Blob([workerSource()], { type: 'text/javascript' }));
      const w = new Worker(workerUrl);
      const self = this;
      w.onmessage = function (e) { self.finish(e.data); };
      w.onerror = function (e) {
        if (e && e.preventDefault) e.preventDefault();
        self.fallback(positions);
      };
      const copy = positions.slice();
      w.postMessage({ type: 'init', positions: copy, texW: TEX_W }, [copy.buffer]);
      this.worker = w;
    } catch (err) {
      this.fallback(positions);
    }
    this.positions = positions;
  }
  Sorter.prototype.fallback = function (positions) {
    if (this.worker) { try { this.worker.terminate(); } catch (e) { /* ignore */ } }
    this.worker = null;
    if (!this.core) {
      this.core = tsSortCore(TEX_W);
      this.core.init(positions);
    }
    if (this.busy && this.pending) { // re-run the request that the worker lost
      const p = this.pending;
      this.busy = false;
      this.request(p.row, p.meta);
    }
  };
  Sorter.prototype.request = function (row, meta) {
    if (this.busy) return false;
    this.busy = true;
    const id = this.nextId++;
    this.pending = { id: id, row: row.slice(), meta: meta };
    if (this.worker) {
      this.worker.postMessage({ type: 'sort', id: id, row: row, near: NEAR });
    } else {
      const self = this;
      setTimeout(function () {
        const r = self.core.sort(row, NEAR);
        self.finish({ id: id, order: r.order, count: r.count, ms: r.ms });
      }, 0);
    }
    return true;
  };
  Sorter.prototype.finish = function (msg) {
    const p = this.pending;
    if (!p || p.id !== msg.id) return;
    this.busy = false;
    this.pending = null;
    this.onResult(msg, p.row, p.meta);
  };
  Sorter.prototype.dispose = function () {
    if (this.worker) this.worker.terminate();
  };

  /* ------------------------------------------------------------------ */
  /* shaders                                                            */
  /* ------------------------------------------------------------------ */

  const SPLAT_VS = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;
uniform sampler2D u_gA;   // mean.xyz, cov.xx
uniform sampler2D u_gB;   // cov.xy, cov.xz, cov.yy, cov.yz
uniform sampler2D u_gC;   // cov.zz
uniform sampler2D u_col;  // base rgb, opacity
uniform sampler2D u_shR;  // degree-1 SH (f1, f2, f3) per channel
uniform sampler2D u_shG;
uniform sampler2D u_shB;
uniform sampler2D u_layer;
uniform highp usampler2D u_order; // back-to-front Gaussian indices
uniform mat3 u_W;         // world-to-camera rotation
uniform vec3 u_t;
uniform vec3 u_centre;
uniform vec4 u_intr;      // fx, fy, cx, cy
uniform vec2 u_size;      // width, height (pixels)
uniform vec4 u_lim;       // lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg
uniform int u_mode;       // 0 RGB, 1 scalar layer, 2 label layer
uniform bool u_hasSH;
uniform vec3 u_palette[16];
uniform vec4 u_heat[5];
uniform int u_base;         // first sorted slot of this batch
flat out vec2 v_mean;
flat out vec3 v_conic;
flat out vec4 v_color;

vec3 heat(float v) {
  v = clamp(v, 0.0, 1.0);
  vec3 c = u_heat[0].yzw;
  for (int i = 1; i < 5; i++) {
    if (v >= u_heat[i - 1].x) {
      float f = clamp((v - u_heat[i - 1].x) / (u_heat[i].x - u_heat[i - 1].x), 0.0, 1.0);
      c = mix(u_heat[i - 1].yzw, u_heat[i].yzw, f);
    }
  }
  return c;
}

void main() {
  gl_Position = vec4(0.0, 0.0, 2.0, 1.0); // outside the clip volume: culled
  // Indexed quads, four vertices per splat in batches (no instancing: it is about ten
  // times slower on some implementations, SwiftShader among them).
  int slot = u_base + (gl_VertexID >> 2);
  vec2 corner = vec2((gl_VertexID & 1) == 0 ? -1.0 : 1.0, (gl_VertexID & 2) == 0 ? -1.0 : 1.0);
  uint index = texelFetch(u_order, ivec2(slot & ${TEX_W - 1}, slot >> ${TEX_SHIFT}), 0).r;
  ivec2 tc = ivec2(int(index & ${TEX_W - 1}u), int(index >> ${TEX_SHIFT}u));
  vec4 A = texelFetch(u_gA, tc, 0);
  vec3 t = u_W * A.xyz + u_t;
  if (!(t.z > ${NEAR.toFixed(4)})) return;
  vec4 col = texelFetch(u_col, tc, 0);
  float thr = log(255.0 * col.a); // alpha >= 1/255 needs sigma <= thr
  if (!(thr > 0.0)) return;
  vec4 B = texelFetch(u_gB, tc, 0);
  float czz = texelFetch(u_gC, tc, 0).r;
  mat3 S = mat3(A.w, B.x, B.y, B.x, B.z, B.w, B.y, B.w, czz);
  float rz = 1.0 / t.z;
  float cx = clamp(t.x * rz, -u_lim.y, u_lim.x);
  float cy = clamp(t.y * rz, -u_lim.w, u_lim.z);
  vec3 j0 = vec3(u_intr.x * rz, 0.0, -u_intr.x * cx * rz);
  vec3 j1 = vec3(0.0, u_intr.y * rz, -u_intr.y * cy * rz);
  vec3 a0 = j0 * u_W; // rows of J W
  vec3 a1 = j1 * u_W;
  vec3 Sa0 = S * a0;
  vec3 Sa1 = S * a1;
  float c00 = dot(a0, Sa0) + 0.3;
  float c01 = dot(a0, Sa1);
  float c11 = dot(a1, Sa1) + 0.3;
  float det = c00 * c11 - c01 * c01;
  if (!(det > 0.0)) return;
  vec2 mean = vec2(u_intr.x * t.x * rz + u_intr.z, u_intr.y * t.y * rz + u_intr.w);
  // Quad along the eigenvectors of the 2D covariance, covering sigma <= thr.
  float mid = 0.5 * (c00 + c11);
  float rad = length(vec2(0.5 * (c00 - c11), c01));
  float l1 = mid + rad;
  float l2 = max(mid - rad, 0.0);
  vec2 va = vec2(c01, l1 - c00);
  vec2 vb = vec2(l1 - c11, c01);
  vec2 e1 = dot(va, va) >= dot(vb, vb) ? va : vb;
  float el = length(e1);
  e1 = el > 0.0 ? e1 / el : vec2(1.0, 0.0);
  vec2 e2 = vec2(-e1.y, e1.x);
  float k = sqrt(2.0 * thr) * 1.001;
  vec2 px = mean + corner.x * e1 * (k * sqrt(l1) + 0.02) + corner.y * e2 * (k * sqrt(l2) + 0.02);
  gl_Position = vec4(px.x / u_size.x * 2.0 - 1.0, 1.0 - px.y / u_size.y * 2.0, 0.0, 1.0);
  v_mean = mean;
  v_conic = vec3(c11, -c01, c00) / det;
  vec3 c;
  if (u_mode == 1) {
    c = heat(texelFetch(u_layer, tc, 0).r);
  } else if (u_mode == 2) {
    int id = int(texelFetch(u_layer, tc, 0).r * 255.0 + 0.5);
    c = u_palette[id % 16];
  } else {
    c = col.rgb;
    if (u_hasSH) {
      vec3 d = A.xyz - u_centre;
      d = d / max(length(d), 1e-12);
      vec3 basis = vec3(-${SH_C1} * d.y, ${SH_C1} * d.z, -${SH_C1} * d.x);
      c += vec3(dot(basis, texelFetch(u_shR, tc, 0).xyz),
                dot(basis, texelFetch(u_shG, tc, 0).xyz),
                dot(basis, texelFetch(u_shB, tc, 0).xyz));
    }
    c = max(c, 0.0);
  }
  v_color = vec4(c, col.a);
}
`;

  const SPLAT_FS = `#version 300 es
precision highp float;
uniform float u_height;
flat in vec2 v_mean;
flat in vec3 v_conic;
flat in vec4 v_color;
out vec4 o_color;
void main() {
  // Pixel centre in image coordinates (origin top-left, centres at +0.5).
  vec2 d = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y) - v_mean;
  float sigma = 0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) + v_conic.y * d.x * d.y;
  if (sigma < 0.0) discard;
  float alpha = min(0.999, v_color.a * exp(-sigma));
  if (alpha < 1.0 / 255.0) discard;
  o_color = vec4(v_color.rgb * alpha, alpha); // premultiplied
}
`;

  const COMPOSITE_VS = `#version 300 es
void main() {
  vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}
`;

  const COMPOSITE_FS = `#version 300 es
precision highp float;
uniform highp sampler2D u_acc;
uniform vec3 u_bg;
out vec4 o_color;
void main() {
  vec4 c = texelFetch(u_acc, ivec2(gl_FragCoord.xy), 0);
  o_color = vec4(c.rgb + (1.0 - c.a) * u_bg, 1.0);
}
`;

  function compile(gl, type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS) && !gl.isContextLost()) {
      throw new Error('shader compilation failed: ' + gl.getShaderInfoLog(s));
    }
    return s;
  }

  function program(gl, vs, fs, attribs) {
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vs));
    gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fs));
    if (attribs) for (const name in attribs) gl.bindAttribLocation(p, attribs[name], name);
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS) && !gl.isContextLost()) {
      throw new Error('shader link failed: ' + gl.getProgramInfoLog(p));
    }
    const u = {};
    const nu = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < nu; i++) {
      const info = gl.getActiveUniform(p, i);
      const name = info.name.replace(/\[0\]$/, '');
      u[name] = gl.getUniformLocation(p, info.name);
    }
    return { prog: p, u: u };
  }

  /** A new bound 2D texture with nearest filtering and clamped edges. */
  function nearestTexture(gl) {
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    return t;
  }

  function dataTexture(gl, internal, format, type, rows, data) {
    const t = nearestTexture(gl);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.texImage2D(gl.TEXTURE_2D, 0, internal, TEX_W, rows, 0, format, type, data);
    return t;
  }

  /** A zero-padded texel array of `rows` x TEX_W texels of `outW` floats; fill(out, i, k)
   * writes Gaussian i at out[k..k+outW). */
  function pack(n, rows, outW, fill) {
    const out = new Float32Array(TEX_W * rows * outW);
    for (let i = 0; i < n; i++) fill(out, i, i * outW);
    return out;
  }

  /* ------------------------------------------------------------------ */
  /* the viewer                                                         */
  /* ------------------------------------------------------------------ */

  function create(root) {
    if (root.tsViewer) return root.tsViewer;

    let readyResolve, readyReject;
    const ready = new Promise(function (res, rej) { readyResolve = res; readyReject = rej; });
    ready.catch(function () { /* reported in the page; awaiting callers still see it */ });

    let failed = null;
    let cssRect = { x: 0, y: 0, w: 1, h: 1 }; // canvas rectangle inside the stage (CSS px)
    let benchmarking = false;
    let lastBench = null;
    const S = {
      meta: null,
      gl: null,
      scenes: [],       // {name, count, dropped, geom, colTex, shTex, rows}
      geoms: [],        // {n, pos, texA, texB, texC, orderTex, sorter, count, sortedRow, ...}
      layers: [],       // {name, kind, scene, tex, max}
      cameras: [],
      shared: false,
      scene: 0,         // shown scene when not split
      split: null,      // fraction, or null
      mode: 'RGB',
      sizeMode: 'camera',
      camIndex: -1,     // camera whose exact view is shown, -1 after moving
      showCams: true,
      view: null,       // {R (row-major 9), t, fx, fy, cx, cy, w, h}
      base: null,       // intrinsics the view derives from: {fx, fy, cx, cy, w, h}
      target: [0, 0, 0],
      up: [0, -1, 0],
      dirty: true,
      frameWaiters: [],
      drawTimes: [],
      fps: 0,
      drawn: 0,
      sortMs: 0,
      loaded: false,
      bgColour: [0, 0, 0],
      accFormat: 'RGBA8',
    };

    const api = {
      ready: ready,
      setCamera: function (i) { guard(); selectCamera(resolveCamera(i)); return api; },
      setScene: function (name) { guard(); chooseScene(resolveScene(name)); return api; },
      setSplit: function (f) { guard(); chooseSplit(f); return api; },
      setColourMode: function (name) { guard(); chooseColour(resolveColour(name)); return api; },
      setSizeMode: function (m) { guard(); chooseSize(m); return api; },
      showCameras: function (on) { guard(); S.showCams = !!on; ui.showCams.checked = S.showCams; markDirty(); return api; },
      frame: frame,
      stats: stats,
      benchmark: benchmark,
      camera: function () {
        const v = S.view;
        return v ? {
          rotation: [[v.R[0], v.R[1], v.R[2]], [v.R[3], v.R[4], v.R[5]], [v.R[6], v.R[7], v.R[8]]],
          translation: v.t.slice(), fx: v.fx, fy: v.fy, cx: v.cx, cy: v.cy, width: v.w, height: v.h,
          index: S.camIndex,
        } : null;
      },
      orbit: function (dx, dy) { guard(); orbit(dx, dy); return api; },
    };
    root.tsViewer = api;
    if (!window.transsplatViewers) window.transsplatViewers = [];
    window.transsplatViewers.push(api);

    function guard() {
      if (failed) throw failed;
    }

    /* ---------------- UI skeleton ---------------- */
    const ui = {};
    ui.bar = el('div', 'ts-toolbar', null);
    ui.title = el('span', 'ts-title', ui.bar);
    ui.sceneGroup = el('span', 'ts-group ts-scene-group', ui.bar);
    ui.before = el('button', 'ts-before', ui.sceneGroup, 'before');
    ui.after = el('button', 'ts-after', ui.sceneGroup, 'after');
    ui.splitLabel = el('label', 'ts-split-label', ui.sceneGroup);
    ui.splitOn = el('input', 'ts-split-on', ui.splitLabel);
    ui.splitOn.type = 'checkbox';
    el('span', null, ui.splitLabel, 'split');
    ui.split = el('input', 'ts-split', ui.sceneGroup);
    ui.split.type = 'range';
    ui.split.min = '0';
    ui.split.max = '1';
    ui.split.step = '0.001';
    ui.split.value = '0.5';
    ui.split.title = 'split position: before on the left, after on the right';
    const camGroup = el('span', 'ts-group', ui.bar);
    el('span', 'ts-label', camGroup, 'view');
    ui.camera = el('select', 'ts-camera', camGroup);
    ui.size = el('select', 'ts-size', camGroup);
    for (const [v, t] of [['camera', 'camera size'], ['fill', 'fill']]) {
      const o = el('option', null, ui.size, t);
      o.value = v;
    }
    ui.camsLabel = el('label', 'ts-cams-label', camGroup);
    const camsLabel = ui.camsLabel;
    ui.showCams = el('input', 'ts-show-cams', camsLabel);
    ui.showCams.type = 'checkbox';
    ui.showCams.checked = true;
    el('span', null, camsLabel, 'cameras');
    const colGroup = el('span', 'ts-group', ui.bar);
    el('span', 'ts-label', colGroup, 'colour');
    ui.colour = el('select', 'ts-colour', colGroup);
    ui.fpsEl = el('span', 'ts-fps', ui.bar, '');

    ui.stage = el('div', 'ts-stage', null);
    ui.stage.tabIndex = 0;
    ui.canvas = el('canvas', 'ts-canvas', ui.stage);
    ui.overlay = el('canvas', 'ts-overlay', ui.stage);
    ui.divider = el('div', 'ts-divider', ui.stage);
    ui.legend = el('div', 'ts-legend', ui.stage);
    ui.info = el('div', 'ts-info', null);
    ui.counts = el('div', 'ts-counts', ui.info);
    ui.hint = el('div', 'ts-hint', ui.info,
      'left drag: orbit \u00b7 right or shift drag: pan \u00b7 wheel: zoom \u00b7 W/A/S/D/Q/E: move \u00b7 click a camera to jump to it');
    ui.notes = el('ul', 'ts-notes', ui.info);
    ui.message = el('div', 'ts-message', null);
    ui.message.setAttribute('role', 'alert');
    ui.message.hidden = true;

    // Keep the data scripts; put the UI after them.
    root.appendChild(ui.bar);
    root.appendChild(ui.message);
    root.appendChild(ui.stage);
    root.appendChild(ui.info);

    function fail(err) {
      const e = err instanceof Error ? err : new Error(String(err));
      if (!failed) failed = e;
      ui.message.textContent = e.message;
      ui.message.hidden = false;
      ui.message.classList.add('ts-error');
      ui.stage.hidden = true;
      ui.hint.hidden = true;
      ui.bar.classList.add('ts-disabled');
      if (window.console) console.error('transsplat viewer:', e);
      readyReject(e);
      const w = S.frameWaiters;
      S.frameWaiters = [];
      for (const f of w) f.reject(e);
    }

    function showStatus(text) {
      ui.message.textContent = text;
      ui.message.classList.remove('ts-error');
      ui.message.hidden = !text;
    }

    /* ---------------- META ---------------- */
    function readMeta() {
      const node = root.querySelector('script.ts-meta');
      if (!node) throw new Error('invalid viewer data: no <script class="ts-meta"> element');
      let meta;
      try {
        meta = JSON.parse(node.textContent);
      } catch (e) {
        throw new Error('invalid viewer data: the META JSON does not parse (' + e.message + ')');
      }
      if (!meta || typeof meta !== 'object') throw new Error('invalid viewer data: META is not an object');
      const bad = function (m) { throw new Error('invalid viewer data: ' + m); };
      meta.title = typeof meta.title === 'string' ? meta.title : '';
      const bg = meta.background === undefined ? [0, 0, 0] : meta.background;
      if (!Array.isArray(bg) || bg.length !== 3 || !bg.every(isNum)) bad('"background" must be three numbers');
      meta.background = bg;
      const scenes = meta.scenes === undefined ? [] : meta.scenes;
      if (!Array.isArray(scenes) || scenes.length > 2) bad('"scenes" must be a list of at most two scenes');
      scenes.forEach(function (s, i) {
        if (!s || typeof s !== 'object') bad('scene ' + i + ' is not an object');
        if (typeof s.name !== 'string') s.name = i === 0 ? 'before' : 'after';
        if (!isCount(s.blob)) bad('scene ' + i + ': "blob" must be a blob index');
        if (s.count !== undefined && !isCount(s.count)) bad('scene ' + i + ': "count" must be a count');
        if (s.dropped !== undefined && !isCount(s.dropped)) bad('scene ' + i + ': "dropped" must be a count');
      });
      meta.scenes = scenes;
      const layers = meta.layers === undefined ? [] : meta.layers;
      if (!Array.isArray(layers)) bad('"layers" must be a list');
      const names = new Set(['RGB']);
      layers.forEach(function (l, i) {
        if (!l || typeof l !== 'object' || typeof l.name !== 'string' || !l.name) bad('layer ' + i + ' needs a name');
        if (names.has(l.name)) bad('layer name "' + l.name + '" is used twice (or is "RGB")');
        names.add(l.name);
        if (!isCount(l.scene) || l.scene >= scenes.length) bad('layer "' + l.name + '": "scene" must index a scene');
        if (!isCount(l.blob)) bad('layer "' + l.name + '": "blob" must be a blob index');
        if (l.kind !== 'scalar' && l.kind !== 'label') bad('layer "' + l.name + '": "kind" must be "scalar" or "label"');
      });
      meta.layers = layers;
      const cams = meta.cameras === undefined ? [] : meta.cameras;
      if (!Array.isArray(cams)) bad('"cameras" must be a list');
      cams.forEach(function (c, i) {
        const what = 'camera ' + i;
        if (!c || typeof c !== 'object') bad(what + ' is not an object');
        if (!(Number.isInteger(c.width) && c.width > 0 && Number.isInteger(c.height) && c.height > 0)) {
          bad(what + ': width and height must be positive integers');
        }
        for (const k of ['fx', 'fy', 'cx', 'cy']) if (!isNum(c[k])) bad(what + ': "' + k + '" must be a number');
        if (!(c.fx > 0 && c.fy > 0)) bad(what + ': focal lengths must be positive');
        const R = c.rotation;
        if (!Array.isArray(R) || R.length !== 3 || !R.every(function (r) { return Array.isArray(r) && r.length === 3 && r.every(isNum); })) {
          bad(what + ': "rotation" must be a 3x3 list of numbers');
        }
        if (!Array.isArray(c.translation) || c.translation.length !== 3 || !c.translation.every(isNum)) {
          bad(what + ': "translation" must be three numbers');
        }
        if (typeof c.name !== 'string') c.name = String(c.name === undefined ? i : c.name);
        if (typeof c.role !== 'string') c.role = 'train';
      });
      meta.cameras = cams;
      if (meta.start_camera === undefined || meta.start_camera === null) meta.start_camera = 0;
      if (!Number.isInteger(meta.start_camera)) bad('"start_camera" must be an integer');
      const notes = meta.notes === undefined ? [] : meta.notes;
      if (!Array.isArray(notes)) bad('"notes" must be a list of strings');
      meta.notes = notes.map(String);
      meta.shared_geometry = !!meta.shared_geometry;
      return meta;
    }

    function blobText(index) {
      const nodes = root.querySelectorAll('script.ts-blob');
      for (const n of nodes) {
        if (n.getAttribute('data-blob') === String(index)) return n.textContent;
      }
      throw new Error('invalid viewer data: blob ' + index + ' is missing');
    }

    /* ---------------- synchronous start: META, UI, WebGL ---------------- */
    let gl = null;
    let progSplat = null, progComp = null, emptyVao = null, quadVao = null;
    let acc = null; // {tex, fbo, w, h}
    try {
      S.meta = readMeta();
      buildControls();
      const canvas = ui.canvas;
      try {
        gl = canvas.getContext('webgl2', {
          alpha: false, premultipliedAlpha: false, antialias: false, depth: false, stencil: false,
          preserveDrawingBuffer: true, powerPreference: 'high-performance',
        });
      } catch (e) {
        gl = null;
      }
      if (!gl) throw new Error(WEBGL2_MESSAGE);
      S.gl = gl;
      S.accFormat = gl.getExtension('EXT_color_buffer_float') ? 'RGBA16F' : 'RGBA8';
      progSplat = program(gl, SPLAT_VS, SPLAT_FS);
      progComp = program(gl, COMPOSITE_VS, COMPOSITE_FS);
      emptyVao = gl.createVertexArray(); // the composite pass draws from gl_VertexID alone
      // Splats: batches of BATCH quads from one static Uint16 index buffer; the vertex
      // shader derives the sorted slot and the corner from gl_VertexID and u_base.
      quadVao = gl.createVertexArray();
      gl.bindVertexArray(quadVao);
      const ib = new Uint16Array(BATCH * 6);
      for (let j = 0; j < BATCH; j++) {
        ib.set([4 * j, 4 * j + 1, 4 * j + 2, 4 * j + 2, 4 * j + 1, 4 * j + 3], 6 * j);
      }
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer());
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, ib, gl.STATIC_DRAW);
      gl.bindVertexArray(null);
      canvas.addEventListener('webglcontextlost', function (e) {
        e.preventDefault();
        fail(new Error('The WebGL context was lost (GPU reset or out of memory); reload the page.'));
      });
      S.bgColour = S.meta.background.slice();
      ui.stage.style.backgroundColor = cssColour(S.bgColour);
      bindEvents();
    } catch (e) {
      fail(e);
      return api;
    }

    start().catch(fail);
    return api;

    /* ---------------- asynchronous start: data ---------------- */
    async function start() {
      const meta = S.meta;
      showStatus('Loading\u2026');
      await nextTask();
      const decoded = [];
      for (let i = 0; i < meta.scenes.length; i++) {
        const s = meta.scenes[i];
        const what = 'scene "' + s.name + '" (blob ' + s.blob + ')';
        const bytes = decodeBase64(blobText(s.blob), what);
        const d = decodeScene(bytes, what);
        if (s.count !== undefined && s.count !== d.n) {
          throw new Error('invalid viewer data: ' + what + ' has ' + d.n + ' Gaussians, META says ' + s.count);
        }
        decoded.push(d);
        await nextTask();
      }
      S.shared = meta.shared_geometry && decoded.length === 2 && decoded[0].n === decoded[1].n;
      if (meta.shared_geometry && decoded.length === 2 && !S.shared) {
        el('li', null, ui.notes, 'shared_geometry ignored: the two scenes have different Gaussian counts');
      }
      const maxRows = gl.getParameter(gl.MAX_TEXTURE_SIZE);
      for (let i = 0; i < decoded.length; i++) {
        const d = decoded[i];
        const rows = Math.max(1, Math.ceil(d.n / TEX_W));
        if (rows > maxRows) {
          throw new Error('scene "' + meta.scenes[i].name + '" has ' + fmtInt(d.n) +
            ' Gaussians, more than this GPU can hold in one texture (' + fmtInt(TEX_W * maxRows) + ')');
        }
        let geom;
        if (i === 1 && S.shared) {
          geom = S.geoms[0];
        } else {
          geom = makeGeometry(d, rows);
          S.geoms.push(geom);
        }
        const colTex = dataTexture(gl, gl.RGBA32F, gl.RGBA, gl.FLOAT, rows,
          pack(d.n, rows, 4, function (o, g, k) {
            o[k] = d.col[g * 4]; o[k + 1] = d.col[g * 4 + 1]; o[k + 2] = d.col[g * 4 + 2]; o[k + 3] = d.col[g * 4 + 3];
          }));
        let shTex = null;
        if (d.sh) {
          shTex = [0, 1, 2].map(function (ch) {
            return dataTexture(gl, gl.RGBA16F, gl.RGBA, gl.FLOAT, rows, pack(d.n, rows, 4, function (o, g, k) {
              o[k] = d.sh[g * 9 + ch * 3]; o[k + 1] = d.sh[g * 9 + ch * 3 + 1]; o[k + 2] = d.sh[g * 9 + ch * 3 + 2];
            }));
          });
        }
        S.scenes.push({
          name: meta.scenes[i].name, count: d.n, dropped: meta.scenes[i].dropped || 0,
          geom: geom, colTex: colTex, shTex: shTex, rows: rows,
        });
        await nextTask();
      }
      for (const l of meta.layers) {
        const sc = S.scenes[l.scene];
        const bytes = decodeBase64(blobText(l.blob), 'layer "' + l.name + '"');
        if (bytes.length !== sc.count) {
          throw new Error('invalid viewer data: layer "' + l.name + '" has ' + bytes.length +
            ' values for the ' + sc.count + ' Gaussians of scene "' + sc.name + '"');
        }
        const padded = new Uint8Array(TEX_W * sc.rows);
        padded.set(bytes);
        const tex = dataTexture(gl, gl.R8, gl.RED, gl.UNSIGNED_BYTE, sc.rows, padded);
        let maxv = 0;
        for (let i = 0; i < bytes.length; i++) if (bytes[i] > maxv) maxv = bytes[i];
        S.layers.push({ name: l.name, kind: l.kind, scene: l.scene, tex: tex, max: maxv });
      }
      S.loaded = true;
      showStatus('');
      renderInfo();
      // Initial view: the URL hash, else the start camera.
      const hash = parseHash();
      if (!S.view) {
        let ci = S.cameras.length ? Math.min(Math.max(0, S.meta.start_camera), S.cameras.length - 1) : -1;
        if (hash.camera !== undefined) {
          try { ci = resolveCamera(hash.camera); } catch (e) { /* ignore a bad hash */ }
        }
        if (ci >= 0) selectCamera(ci); else defaultView();
      } else {
        S.target = estimateTarget(S.view);
      }
      try { if (hash.size) chooseSize(hash.size); } catch (e) { /* ignore */ }
      try { if (hash.scene) chooseScene(resolveScene(hash.scene)); } catch (e) { /* ignore */ }
      try { if (hash.split) chooseSplit(Number(hash.split)); } catch (e) { /* ignore */ }
      try { if (hash.colour || hash.color) chooseColour(resolveColour(hash.colour || hash.color)); } catch (e) { /* ignore */ }
      syncUI();
      requestAnimationFrame(tick);
      await frame();
      readyResolve(api);
    }

    function makeGeometry(d, rows) {
      const geom = { n: d.n, pos: d.pos, rows: rows };
      geom.texA = dataTexture(gl, gl.RGBA32F, gl.RGBA, gl.FLOAT, rows, pack(d.n, rows, 4, function (o, g, k) {
        o[k] = d.pos[g * 3]; o[k + 1] = d.pos[g * 3 + 1]; o[k + 2] = d.pos[g * 3 + 2]; o[k + 3] = d.cov[g * 6];
      }));
      geom.texB = dataTexture(gl, gl.RGBA32F, gl.RGBA, gl.FLOAT, rows, pack(d.n, rows, 4, function (o, g, k) {
        o[k] = d.cov[g * 6 + 1]; o[k + 1] = d.cov[g * 6 + 2]; o[k + 2] = d.cov[g * 6 + 3]; o[k + 3] = d.cov[g * 6 + 4];
      }));
      geom.texC = dataTexture(gl, gl.R32F, gl.RED, gl.FLOAT, rows, pack(d.n, rows, 1, function (o, g, k) {
        o[k] = d.cov[g * 6 + 5];
      }));
      geom.orderTex = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, geom.orderTex);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.R32UI, TEX_W, rows);
      geom.count = 0;
      geom.sortedRow = null;
      geom.sortWaiters = [];
      geom.sorter = new Sorter(d.pos, function (msg, row) {
        if (failed) return;
        if (msg.count > 0) {
          gl.bindTexture(gl.TEXTURE_2D, geom.orderTex);
          gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
          gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, TEX_W, msg.order.length / TEX_W, gl.RED_INTEGER, gl.UNSIGNED_INT, msg.order);
        }
        geom.count = msg.count;
        geom.sortedRow = row;
        S.sortMs = msg.ms;
        const w = geom.sortWaiters;
        geom.sortWaiters = [];
        for (const f of w) f();
        markDirty();
      });
      return geom;
    }

    /* ---------------- controls ---------------- */
    function buildControls() {
      const meta = S.meta;
      ui.title.textContent = meta.title;
      ui.title.hidden = !meta.title;
      S.cameras = meta.cameras.map(function (c) {
        const R = [].concat(c.rotation[0], c.rotation[1], c.rotation[2]);
        return {
          name: c.name, role: c.role, R: R, t: c.translation.slice(),
          fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy, w: c.width, h: c.height,
          centre: vScale(mat3TVec(R, c.translation), -1),
        };
      });
      const nScenes = meta.scenes.length;
      ui.sceneGroup.hidden = nScenes < 2;
      if (nScenes >= 1) {
        ui.before.textContent = meta.scenes[0].name;
      }
      if (nScenes >= 2) ui.after.textContent = meta.scenes[1].name;
      ui.camera.textContent = '';
      const free = el('option', null, ui.camera, '\u2014 free view \u2014');
      free.value = '-1';
      S.cameras.forEach(function (c, i) {
        const o = el('option', null, ui.camera, c.name + (c.role ? ' (' + c.role + ')' : ''));
        o.value = String(i);
      });
      // Without cameras only the size mode is left to choose.
      ui.camera.hidden = S.cameras.length === 0;
      ui.camsLabel.hidden = S.cameras.length === 0;
      ui.colour.textContent = '';
      const rgb = el('option', null, ui.colour, 'RGB');
      rgb.value = 'RGB';
      for (const l of meta.layers) {
        const o = el('option', null, ui.colour, l.name + (nScenes > 1 && !meta.shared_geometry ? ' (' + meta.scenes[l.scene].name + ')' : ''));
        o.value = l.name;
      }
      ui.colour.parentNode.hidden = meta.layers.length === 0;
      for (const n of meta.notes) el('li', null, ui.notes, n);
      renderInfo();
    }

    function renderInfo() {
      const parts = [];
      const list = S.loaded ? S.scenes : S.meta.scenes.map(function (s) {
        return { name: s.name, count: s.count, dropped: s.dropped || 0 };
      });
      for (const s of list) {
        let t = s.name + ': ' + (s.count === undefined ? '?' : fmtInt(s.count)) + ' Gaussians';
        if (s.dropped) t += ' (' + fmtInt(s.dropped) + ' dropped)';
        parts.push(t);
      }
      if (!list.length) parts.push('no scene');
      if (S.cameras.length) parts.push(S.cameras.length + ' cameras');
      ui.counts.textContent = parts.join(' \u00b7 ');
    }

    function syncUI() {
      const two = S.scenes.length === 2 || S.meta.scenes.length === 2;
      ui.before.classList.toggle('ts-active', two && S.split === null && S.scene === 0);
      ui.after.classList.toggle('ts-active', two && S.split === null && S.scene === 1);
      ui.splitOn.checked = S.split !== null;
      ui.split.classList.toggle('ts-inactive', S.split === null);
      if (S.split !== null) ui.split.value = String(S.split);
      ui.camera.value = String(S.camIndex);
      ui.size.value = S.sizeMode;
      ui.colour.value = S.mode;
      ui.showCams.checked = S.showCams;
      const layer = currentLayer();
      ui.legend.hidden = !layer;
      if (layer) renderLegend(layer);
      layout();
    }

    function renderLegend(layer) {
      ui.legend.textContent = '';
      el('div', 'ts-legend-title', ui.legend, layer.name);
      if (layer.kind === 'scalar') {
        const bar = el('div', 'ts-legend-bar', ui.legend);
        bar.style.background = 'linear-gradient(to right, ' + HEAT.map(function (s) {
          return cssColour([s[1], s[2], s[3]]) + ' ' + (s[0] * 100) + '%';
        }).join(', ') + ')';
        const ticks = el('div', 'ts-legend-ticks', ui.legend);
        el('span', null, ticks, '0');
        el('span', null, ticks, '1');
      } else {
        const n = Math.min(16, layer.max + 1);
        for (let i = 0; i < Math.max(2, n); i++) {
          const row = el('span', 'ts-legend-item', ui.legend);
          const sw = el('span', 'ts-swatch', row);
          sw.style.background = cssColour(PALETTE[i]);
          el('span', null, row, String(i));
        }
      }
    }

    function cssColour(c) {
      const b = function (v) { return Math.round(Math.min(1, Math.max(0, v)) * 255); };
      return 'rgb(' + b(c[0]) + ',' + b(c[1]) + ',' + b(c[2]) + ')';
    }

    function parseHash() {
      const out = {};
      try {
        const h = (window.location.hash || '').replace(/^#/, '');
        const p = new URLSearchParams(h);
        for (const [k, v] of p) out[k] = v;
      } catch (e) { /* ignore */ }
      return out;
    }

    function resolveCamera(i) {
      if (typeof i === 'string') {
        const byName = S.cameras.findIndex(function (c) { return c.name === i; });
        if (byName >= 0) return byName;
        if (/^-?\d+$/.test(i.trim())) i = Number(i);
      }
      if (!Number.isInteger(i) || i < 0 || i >= S.cameras.length) {
        throw new Error('no camera ' + JSON.stringify(i) + ' (there are ' + S.cameras.length + ')');
      }
      return i;
    }

    function resolveScene(name) {
      const names = S.meta.scenes.map(function (s) { return s.name; });
      if (!names.length) throw new Error('there is no scene to show');
      let i = names.indexOf(name);
      if (i < 0 && (name === 'before' || name === 0)) i = 0;
      if (i < 0 && (name === 'after' || name === 1)) i = names.length - 1;
      if (i < 0) throw new Error('no scene ' + JSON.stringify(name) + ' (scenes: ' + names.join(', ') + ')');
      return i;
    }

    function resolveColour(name) {
      if (typeof name !== 'string') throw new Error('colour mode must be a string');
      if (name.toLowerCase() === 'rgb') return 'RGB';
      const exact = S.meta.layers.find(function (l) { return l.name === name; });
      if (exact) return exact.name;
      const loose = S.meta.layers.find(function (l) { return l.name.toLowerCase() === name.toLowerCase(); });
      if (loose) return loose.name;
      throw new Error('no colour mode ' + JSON.stringify(name) + ' (modes: RGB' +
        S.meta.layers.map(function (l) { return ', ' + l.name; }).join('') + ')');
    }

    function chooseScene(i) {
      S.scene = i;
      S.split = null;
      syncUI();
      markDirty();
    }

    function chooseSplit(f) {
      if (f === null || f === undefined || f === false) {
        S.split = null;
      } else {
        if (typeof f !== 'number' || !Number.isFinite(f)) throw new Error('split must be a number in [0, 1] or null');
        if (S.meta.scenes.length < 2) throw new Error('split needs two scenes');
        S.split = Math.min(1, Math.max(0, f));
      }
      syncUI();
      markDirty();
    }

    function chooseColour(name) {
      S.mode = name;
      syncUI();
      markDirty();
    }

    function chooseSize(m) {
      if (m !== 'camera' && m !== 'fill') throw new Error('size mode must be "camera" or "fill"');
      S.sizeMode = m;
      applyIntrinsics();
      syncUI();
      viewChanged(true);
    }

    function currentLayer() {
      if (S.mode === 'RGB') return null;
      return S.layers.find(function (l) { return l.name === S.mode; }) ||
        S.meta.layers.find(function (l) { return l.name === S.mode; }) || null;
    }

    /* ---------------- view state ---------------- */
    function selectCamera(i) {
      const c = S.cameras[i];
      S.camIndex = i;
      S.base = { fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy, w: c.w, h: c.h };
      S.sizeMode = 'camera';
      S.view = { R: c.R.slice(), t: c.t.slice(), fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy, w: c.w, h: c.h };
      S.up = vNorm([-c.R[3], -c.R[4], -c.R[5]]);
      S.target = estimateTarget(S.view);
      syncUI();
      viewChanged(true);
    }

    function defaultView() {
      // No cameras: look at the Gaussians' centre from -z, y down (OpenCV-like).
      const b = bounds();
      const w = Math.max(64, ui.stage.clientWidth || 800);
      const h = Math.max(64, ui.stage.clientHeight || 600);
      const f = 0.5 * h / Math.tan(Math.PI / 6);
      S.base = { fx: f, fy: f, cx: w / 2, cy: h / 2, w: w, h: h };
      S.sizeMode = 'fill';
      const C = [b.centre[0], b.centre[1], b.centre[2] - 2.5 * b.radius];
      const R = [1, 0, 0, 0, 1, 0, 0, 0, 1];
      S.view = { R: R, t: vScale(mat3Vec(R, C), -1), fx: f, fy: f, cx: w / 2, cy: h / 2, w: w, h: h };
      S.up = [0, -1, 0];
      S.target = b.centre;
      S.camIndex = -1;
      applyIntrinsics();
      syncUI();
      viewChanged(true);
    }

    function bounds() {
      const g = S.geoms[0];
      if (!g || !g.n) {
        if (S.cameras.length) {
          const c = S.cameras.reduce(function (a, k) { return vAdd(a, k.centre); }, [0, 0, 0]);
          return { centre: vScale(c, 1 / S.cameras.length), radius: 1 };
        }
        return { centre: [0, 0, 0], radius: 1 };
      }
      if (g.bounds) return g.bounds;
      const step = Math.max(1, Math.floor(g.n / 50000));
      const xs = [[], [], []];
      for (let i = 0; i < g.n; i += step) {
        for (let a = 0; a < 3; a++) xs[a].push(g.pos[i * 3 + a]);
      }
      const lo = [], hi = [], centre = [];
      for (let a = 0; a < 3; a++) {
        xs[a].sort(function (p, q) { return p - q; });
        const m = xs[a].length;
        lo.push(xs[a][Math.floor(m * 0.02)]);
        hi.push(xs[a][Math.min(m - 1, Math.floor(m * 0.98))]);
        centre.push(xs[a][Math.floor(m / 2)]);
      }
      g.bounds = { centre: centre, radius: Math.max(1e-3, 0.5 * vLen(vSub(hi, lo))) };
      return g.bounds;
    }

    /** Orbit target in front of a view: the median depth of the Gaussians it sees. */
    function estimateTarget(v) {
      const C = centreOf(v);
      const f = [v.R[6], v.R[7], v.R[8]];
      const g = S.geoms[0];
      let depth = 0;
      if (g && g.n) {
        const step = Math.max(1, Math.floor(g.n / 40000));
        const zs = [];
        const tx = 0.5 * v.w / v.fx;
        const ty = 0.5 * v.h / v.fy;
        for (let i = 0; i < g.n; i += step) {
          const p = [g.pos[i * 3], g.pos[i * 3 + 1], g.pos[i * 3 + 2]];
          const q = vAdd(mat3Vec(v.R, p), v.t);
          if (q[2] > NEAR && Math.abs(q[0]) < 1.2 * tx * q[2] && Math.abs(q[1]) < 1.2 * ty * q[2]) zs.push(q[2]);
        }
        if (zs.length) {
          zs.sort(function (a, b) { return a - b; });
          depth = zs[zs.length >> 1];
        }
      }
      if (!(depth > 0)) {
        const b = bounds();
        depth = Math.max(0.1 * b.radius, vLen(vSub(b.centre, C)));
      }
      return vAdd(C, vScale(f, depth));
    }

    function centreOf(v) {
      return vScale(mat3TVec(v.R, v.t), -1);
    }

    function setPose(R, C) {
      S.view.R = R;
      S.view.t = vScale(mat3Vec(R, C), -1);
    }

    /** Intrinsics and drawing-buffer size of the view from the size mode. */
    function applyIntrinsics() {
      const v = S.view;
      const b = S.base;
      if (!v || !b) return;
      if (S.sizeMode === 'camera') {
        v.fx = b.fx; v.fy = b.fy; v.cx = b.cx; v.cy = b.cy; v.w = b.w; v.h = b.h;
      } else {
        const dpr = window.devicePixelRatio || 1;
        const sw = Math.max(16, ui.stage.clientWidth || b.w);
        const sh = Math.max(16, ui.stage.clientHeight || b.h);
        const w = Math.max(1, Math.min(4096, Math.round(sw * dpr)));
        const h = Math.max(1, Math.min(4096, Math.round(sh * dpr)));
        const s = h / b.h;
        v.fx = b.fx * s; v.fy = b.fy * s;
        v.cx = w / 2 + (b.cx - b.w / 2) * s;
        v.cy = h / 2 + (b.cy - b.h / 2) * s;
        v.w = w; v.h = h;
      }
    }

    function viewChanged(exact) {
      if (!exact && S.camIndex !== -1) {
        S.camIndex = -1;
        ui.camera.value = '-1';
      }
      layout();
      markDirty();
    }

    function orbit(dx, dy) {
      if (!S.view) return;
      const v = S.view;
      const C = centreOf(v);
      const right = [v.R[0], v.R[1], v.R[2]];
      const Q = mat3Mul(axisAngle(S.up, -dx * 0.005), axisAngle(right, -dy * 0.005));
      const C2 = vAdd(S.target, mat3Vec(Q, vSub(C, S.target)));
      setPose(orthonormalise(mat3Mul(v.R, mat3T(Q))), C2);
      viewChanged(false);
    }

    function pan(dx, dy) {
      const v = S.view;
      const C = centreOf(v);
      const dist = Math.max(1e-6, vLen(vSub(S.target, C)));
      const s = dist / v.fy;
      const move = vAdd(vScale([v.R[0], v.R[1], v.R[2]], -dx * s), vScale([v.R[3], v.R[4], v.R[5]], -dy * s));
      S.target = vAdd(S.target, move);
      setPose(v.R, vAdd(C, move));
      viewChanged(false);
    }

    function zoom(factor) {
      const v = S.view;
      const C = centreOf(v);
      const f = [v.R[6], v.R[7], v.R[8]];
      const dist = Math.max(1e-6, vLen(vSub(S.target, C)));
      const nd = Math.max(1e-4, dist * factor);
      setPose(v.R, vSub(S.target, vScale(f, nd)));
      viewChanged(false);
    }

    function move(forward, sideways, upward) {
      const v = S.view;
      const C = centreOf(v);
      const dist = Math.max(1e-3, vLen(vSub(S.target, C)));
      const step = 0.05 * dist;
      const d = vAdd(vAdd(vScale([v.R[6], v.R[7], v.R[8]], forward * step), vScale([v.R[0], v.R[1], v.R[2]], sideways * step)),
        vScale([v.R[3], v.R[4], v.R[5]], -upward * step));
      S.target = vAdd(S.target, d);
      setPose(v.R, vAdd(C, d));
      viewChanged(false);
    }

    /* ---------------- layout (canvas size and CSS fit) ---------------- */
    function layout() {
      const v = S.view;
      if (!v || !gl) return;
      if (S.sizeMode === 'fill') applyIntrinsics();
      const c = ui.canvas;
      if (c.width !== v.w) c.width = v.w;
      if (c.height !== v.h) c.height = v.h;
      const sw = ui.stage.clientWidth || v.w;
      const sh = ui.stage.clientHeight || v.h;
      let w, h;
      if (S.sizeMode === 'fill') {
        w = sw; h = sh;
      } else {
        const s = Math.min(sw / v.w, sh / v.h);
        w = v.w * s; h = v.h * s;
      }
      const x = (sw - w) / 2;
      const y = (sh - h) / 2;
      cssRect = { x: x, y: y, w: w, h: h };
      c.style.left = x + 'px';
      c.style.top = y + 'px';
      c.style.width = w + 'px';
      c.style.height = h + 'px';
      // The camera overlay covers the whole stage (frustums may lie outside the image).
      const o = ui.overlay;
      o.style.left = '0px';
      o.style.top = '0px';
      o.style.width = sw + 'px';
      o.style.height = sh + 'px';
      const dpr = window.devicePixelRatio || 1;
      const ow = Math.max(1, Math.round(sw * dpr));
      const oh = Math.max(1, Math.round(sh * dpr));
      if (ui.overlay.width !== ow) ui.overlay.width = ow;
      if (ui.overlay.height !== oh) ui.overlay.height = oh;
      ui.divider.hidden = S.split === null;
      if (S.split !== null) ui.divider.style.left = (x + w * S.split) + 'px';
      ui.divider.style.top = y + 'px';
      ui.divider.style.height = h + 'px';
      markDirty();
    }

    /* ---------------- events ---------------- */
    function bindEvents() {
      ui.before.addEventListener('click', function () { chooseScene(0); });
      ui.after.addEventListener('click', function () { chooseScene(1); });
      ui.splitOn.addEventListener('change', function () {
        chooseSplit(ui.splitOn.checked ? Number(ui.split.value) : null);
      });
      ui.split.addEventListener('input', function () { chooseSplit(Number(ui.split.value)); });
      ui.camera.addEventListener('change', function () {
        const i = Number(ui.camera.value);
        if (i >= 0) selectCamera(i);
      });
      ui.size.addEventListener('change', function () { chooseSize(ui.size.value); });
      ui.colour.addEventListener('change', function () { chooseColour(ui.colour.value); });
      ui.showCams.addEventListener('change', function () { S.showCams = ui.showCams.checked; markDirty(); });

      let drag = null;
      ui.divider.addEventListener('pointerdown', function (e) {
        e.stopPropagation();
        e.preventDefault();
        ui.divider.setPointerCapture(e.pointerId);
        drag = { kind: 'divider' };
      });
      ui.divider.addEventListener('pointermove', function (e) {
        if (!drag || drag.kind !== 'divider') return;
        const r = ui.stage.getBoundingClientRect();
        chooseSplit((e.clientX - r.left - cssRect.x) / cssRect.w);
      });
      ui.divider.addEventListener('pointerup', function () { drag = null; });

      const stage = ui.stage;
      stage.addEventListener('contextmenu', function (e) { e.preventDefault(); });
      stage.addEventListener('pointerdown', function (e) {
        if (!S.view || failed) return;
        stage.focus({ preventScroll: true });
        stage.setPointerCapture(e.pointerId);
        const panMode = e.button === 2 || e.button === 1 || e.shiftKey;
        drag = { kind: panMode ? 'pan' : 'orbit', x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, moved: false };
        e.preventDefault();
      });
      stage.addEventListener('pointermove', function (e) {
        if (!drag || drag.kind === 'divider') return;
        const dx = e.clientX - drag.x;
        const dy = e.clientY - drag.y;
        drag.x = e.clientX;
        drag.y = e.clientY;
        if (Math.abs(e.clientX - drag.x0) + Math.abs(e.clientY - drag.y0) > 3) drag.moved = true;
        if (!drag.moved) return;
        if (drag.kind === 'orbit') {
          orbit(dx, dy);
        } else {
          const k = S.view.w / Math.max(1, cssRect.w); // CSS px to drawing-buffer px
          pan(dx * k, dy * k);
        }
      });
      stage.addEventListener('pointerup', function (e) {
        if (!drag || drag.kind === 'divider') return;
        const d = drag;
        drag = null;
        if (!d.moved && e.button === 0) pickCamera(e);
      });
      stage.addEventListener('pointercancel', function () { drag = null; });
      stage.addEventListener('wheel', function (e) {
        if (!S.view) return;
        e.preventDefault();
        let d = e.deltaY;
        if (e.deltaMode === 1) d *= 30;
        else if (e.deltaMode === 2) d *= 300;
        zoom(Math.exp(Math.max(-300, Math.min(300, d)) * 0.0015));
      }, { passive: false });
      stage.addEventListener('keydown', function (e) {
        if (!S.view) return;
        const k = e.key.toLowerCase();
        const map = { w: [1, 0, 0], s: [-1, 0, 0], a: [0, -1, 0], d: [0, 1, 0], e: [0, 0, 1], q: [0, 0, -1] };
        if (map[k]) {
          move(map[k][0], map[k][1], map[k][2]);
          e.preventDefault();
        } else if (k === 'arrowleft' || k === 'arrowright') {
          orbit(k === 'arrowleft' ? -20 : 20, 0);
          e.preventDefault();
        } else if (k === 'arrowup' || k === 'arrowdown') {
          orbit(0, k === 'arrowup' ? -20 : 20);
          e.preventDefault();
        }
      });
      if (window.ResizeObserver) {
        new ResizeObserver(function () { layout(); }).observe(ui.stage);
      } else {
        window.addEventListener('resize', layout);
      }
    }

    function pickCamera(e) {
      if (!S.showCams || !S.cameras.length) return;
      const r = ui.stage.getBoundingClientRect();
      const mx = e.clientX - r.left - cssRect.x;
      const my = e.clientY - r.top - cssRect.y;
      let best = -1;
      let bestD = 12;
      S.cameras.forEach(function (c, i) {
        if (i === S.camIndex) return;
        const p = projectCss(c.centre);
        if (!p) return;
        const d = Math.hypot(p[0] - mx, p[1] - my);
        if (d < bestD) { bestD = d; best = i; }
      });
      if (best >= 0) selectCamera(best);
    }

    /** World point to CSS pixels over the canvas, or null behind the camera. */
    function projectCss(p) {
      const v = S.view;
      const q = vAdd(mat3Vec(v.R, p), v.t);
      if (!(q[2] > NEAR)) return null;
      const s = cssRect.w / v.w;
      return [(v.fx * q[0] / q[2] + v.cx) * s, (v.fy * q[1] / q[2] + v.cy) * s];
    }

    /* ---------------- rendering ---------------- */
    function markDirty() {
      S.dirty = true;
    }

    function depthRow() {
      const v = S.view;
      return [v.R[6], v.R[7], v.R[8], v.t[2]];
    }

    function rowClose(a, b) {
      if (!a || !b) return false;
      const tol = 1e-7 * (1 + Math.abs(b[3]));
      return Math.abs(a[0] - b[0]) <= 1e-7 && Math.abs(a[1] - b[1]) <= 1e-7 &&
        Math.abs(a[2] - b[2]) <= 1e-7 && Math.abs(a[3] - b[3]) <= tol;
    }

    /** Geometries the current frame draws. */
    function neededGeoms() {
      const out = [];
      const idx = S.split === null ? [S.scene] : [0, 1];
      for (const i of idx) {
        const sc = S.scenes[i];
        if (sc && out.indexOf(sc.geom) < 0) out.push(sc.geom);
      }
      return out;
    }

    function requestSorts() {
      if (!S.view) return;
      const row = depthRow();
      for (const g of neededGeoms()) {
        if (!rowClose(g.sortedRow, row) && !g.sorter.busy) g.sorter.request(row);
      }
    }

    function upToDate() {
      const row = depthRow();
      return neededGeoms().every(function (g) { return rowClose(g.sortedRow, row); });
    }

    function ensureAcc(w, h) {
      if (acc && acc.w === w && acc.h === h) return;
      if (acc) {
        gl.deleteTexture(acc.tex);
        gl.deleteFramebuffer(acc.fbo);
      }
      const tex = nearestTexture(gl);
      if (S.accFormat === 'RGBA16F') {
        gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA16F, w, h);
      } else {
        gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA8, w, h);
      }
      const fbo = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
      if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE && S.accFormat !== 'RGBA8') {
        gl.bindFramebuffer(gl.FRAMEBUFFER, null);
        gl.deleteFramebuffer(fbo);
        gl.deleteTexture(tex);
        S.accFormat = 'RGBA8';
        acc = null;
        ensureAcc(w, h);
        return;
      }
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      acc = { tex: tex, fbo: fbo, w: w, h: h };
    }

    function draw() {
      const v = S.view;
      const W = gl.drawingBufferWidth;
      const H = gl.drawingBufferHeight;
      ensureAcc(W, H);
      gl.bindFramebuffer(gl.FRAMEBUFFER, acc.fbo);
      gl.viewport(0, 0, W, H);
      gl.disable(gl.SCISSOR_TEST);
      gl.clearColor(0, 0, 0, 0);
      gl.clear(gl.COLOR_BUFFER_BIT);
      let drawn = 0;
      if (v && S.scenes.length) {
        gl.useProgram(progSplat.prog);
        const u = progSplat.u;
        const R = v.R;
        gl.uniformMatrix3fv(u.u_W, false, [R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]]);
        gl.uniform3fv(u.u_t, v.t);
        gl.uniform3fv(u.u_centre, centreOf(v));
        gl.uniform4f(u.u_intr, v.fx, v.fy, v.cx, v.cy);
        gl.uniform2f(u.u_size, W, H);
        const tfx = 0.5 * v.w / v.fx;
        const tfy = 0.5 * v.h / v.fy;
        gl.uniform4f(u.u_lim, (v.w - v.cx) / v.fx + 0.3 * tfx, v.cx / v.fx + 0.3 * tfx,
          (v.h - v.cy) / v.fy + 0.3 * tfy, v.cy / v.fy + 0.3 * tfy);
        gl.uniform1f(u.u_height, H);
        gl.uniform3fv(u.u_palette, [].concat.apply([], PALETTE));
        gl.uniform4fv(u.u_heat, [].concat.apply([], HEAT));
        const units = ['u_gA', 'u_gB', 'u_gC', 'u_col', 'u_shR', 'u_shG', 'u_shB', 'u_layer', 'u_order'];
        units.forEach(function (name, k) { gl.uniform1i(u[name], k); });
        gl.enable(gl.BLEND);
        gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
        gl.blendEquation(gl.FUNC_ADD);
        const parts = [];
        if (S.split === null || S.scenes.length < 2) {
          parts.push({ scene: Math.min(S.scene, S.scenes.length - 1), x0: 0, x1: W });
        } else {
          const xs = Math.round(S.split * W);
          parts.push({ scene: 0, x0: 0, x1: xs });
          parts.push({ scene: 1, x0: xs, x1: W });
        }
        const layer = currentLayer();
        for (const p of parts) {
          if (p.x1 <= p.x0) continue;
          const sc = S.scenes[p.scene];
          const g = sc.geom;
          if (!g.sortedRow || !g.count) continue;
          if (parts.length > 1) {
            gl.enable(gl.SCISSOR_TEST);
            gl.scissor(p.x0, 0, p.x1 - p.x0, H);
          } else {
            gl.disable(gl.SCISSOR_TEST);
          }
          const useLayer = layer && layer.tex && (layer.scene === p.scene || S.shared);
          gl.uniform1i(u.u_mode, useLayer ? (layer.kind === 'scalar' ? 1 : 2) : 0);
          gl.uniform1i(u.u_hasSH, sc.shTex && !useLayer ? 1 : 0);
          const tex = [g.texA, g.texB, g.texC, sc.colTex,
            sc.shTex ? sc.shTex[0] : sc.colTex, sc.shTex ? sc.shTex[1] : sc.colTex, sc.shTex ? sc.shTex[2] : sc.colTex,
            useLayer ? layer.tex : sc.colTex, g.orderTex];
          tex.forEach(function (t, k) {
            gl.activeTexture(gl.TEXTURE0 + k);
            gl.bindTexture(gl.TEXTURE_2D, t);
          });
          gl.bindVertexArray(quadVao);
          for (let base = 0; base < g.count; base += BATCH) {
            gl.uniform1i(u.u_base, base);
            gl.drawElements(gl.TRIANGLES, 6 * Math.min(BATCH, g.count - base), gl.UNSIGNED_SHORT, 0);
          }
          drawn += g.count;
        }
        gl.bindVertexArray(null);
        gl.disable(gl.SCISSOR_TEST);
        gl.disable(gl.BLEND);
        gl.activeTexture(gl.TEXTURE0);
      }
      // Background under the accumulated premultiplied colour, into the canvas.
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, W, H);
      gl.useProgram(progComp.prog);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, acc.tex);
      gl.uniform1i(progComp.u.u_acc, 0);
      gl.uniform3fv(progComp.u.u_bg, S.bgColour);
      gl.bindVertexArray(emptyVao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(null);
      S.drawn = drawn;
      drawOverlay();
    }

    function drawOverlay() {
      const ctx = ui.overlay.getContext('2d');
      const ow = ui.overlay.width;
      const oh = ui.overlay.height;
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.clearRect(0, 0, ow, oh);
      if (!S.showCams || !S.cameras.length || !S.view) return;
      const v = S.view;
      const dpr = ow / Math.max(1, ui.stage.clientWidth || cssRect.w);
      ctx.setTransform(dpr, 0, 0, dpr, cssRect.x * dpr, cssRect.y * dpr);
      const b = bounds();
      let size = 0.06 * b.radius;
      if (S.cameras.length > 1) {
        const cen = vScale(S.cameras.reduce(function (a, c) { return vAdd(a, c.centre); }, [0, 0, 0]), 1 / S.cameras.length);
        const ds = S.cameras.map(function (c) { return vLen(vSub(c.centre, cen)); }).sort(function (a, c) { return a - c; });
        const med = ds[ds.length >> 1];
        if (med > 0) size = 0.08 * med;
      }
      const s = cssRect.w / v.w;
      const near = NEAR;
      const toCam = function (p) { return vAdd(mat3Vec(v.R, p), v.t); };
      const proj = function (q) { return [(v.fx * q[0] / q[2] + v.cx) * s, (v.fy * q[1] / q[2] + v.cy) * s]; };
      const line = function (a, b2) {
        let p = a, q = b2;
        if (p[2] <= near && q[2] <= near) return;
        if (p[2] <= near || q[2] <= near) {
          const f = (near - p[2]) / (q[2] - p[2]);
          const m = vAdd(p, vScale(vSub(q, p), f));
          if (p[2] <= near) p = m; else q = m;
        }
        const A = proj(p), B = proj(q);
        ctx.moveTo(A[0], A[1]);
        ctx.lineTo(B[0], B[1]);
      };
      ctx.lineWidth = 1.25;
      const eye = centreOf(v);
      S.cameras.forEach(function (c, i) {
        // Skip the camera we look through (or stand next to): it would fill the view.
        if (i === S.camIndex || vLen(vSub(c.centre, eye)) < 1.5 * size) return;
        const Cw = c.centre;
        const corner = function (u, w) {
          const d = [(u - c.cx) / c.fx * size, (w - c.cy) / c.fy * size, size];
          return vAdd(mat3TVec(c.R, d), Cw);
        };
        const k = [corner(0, 0), corner(c.w, 0), corner(c.w, c.h), corner(0, c.h)].map(toCam);
        const ctr = toCam(Cw);
        const top = toCam(vAdd(mat3TVec(c.R, [((c.w / 2) - c.cx) / c.fx * size, (-0.25 * c.h - c.cy) / c.fy * size, size]), Cw));
        ctx.beginPath();
        for (let j = 0; j < 4; j++) {
          line(ctr, k[j]);
          line(k[j], k[(j + 1) % 4]);
        }
        line(k[0], top);
        line(top, k[1]);
        ctx.strokeStyle = ROLE_COLOURS[c.role] || OTHER_ROLE_COLOUR;
        ctx.stroke();
      });
    }

    function tick(now) {
      if (failed) return;
      requestAnimationFrame(tick);
      if (!S.loaded || benchmarking) return;
      requestSorts();
      if (!S.dirty) return;
      S.dirty = false;
      draw();
      noteFrame(now);
      resolveFrameWaiters();
    }

    function noteFrame(now) {
      const t = S.drawTimes;
      t.push(now);
      while (t.length && t[0] < now - 1000) t.shift();
      if (t.length >= 2) S.fps = (t.length - 1) * 1000 / (t[t.length - 1] - t[0]);
      ui.fpsEl.textContent = (t.length >= 2 ? S.fps.toFixed(0) : '\u2013') + ' fps \u00b7 ' + fmtInt(S.drawn) + ' drawn \u00b7 sort ' +
        S.sortMs.toFixed(0) + ' ms';
    }

    function resolveFrameWaiters() {
      if (!S.frameWaiters.length || !upToDate()) return;
      const w = S.frameWaiters;
      S.frameWaiters = [];
      for (const f of w) f.resolve();
    }

    function frame() {
      if (failed) return Promise.reject(failed);
      return new Promise(function (resolve, reject) {
        S.frameWaiters.push({ resolve: resolve, reject: reject });
        markDirty();
      });
    }

    function stats() {
      const shown = S.split === null ? [S.scenes[S.scene]] : S.scenes;
      let n = 0;
      for (const s of shown) if (s) n = Math.max(n, s.count);
      return {
        fps: S.fps, gaussians: n, drawn: S.drawn, sortMs: S.sortMs,
        width: gl ? gl.drawingBufferWidth : 0, height: gl ? gl.drawingBufferHeight : 0,
        accumulation: S.accFormat, renderMs: lastBench ? lastBench.renderMs : null,
        sorter: S.geoms.length && !S.geoms.every(function (g) { return g.sorter.worker; }) ? 'main thread' : 'worker',
      };
    }

    /* ---------------- benchmark ---------------- */

    function sortNow(g, row) {
      return new Promise(function (resolve) {
        const go = function () {
          if (rowClose(g.sortedRow, row)) { resolve(); return; }
          g.sortWaiters.push(go);
          if (!g.sorter.busy) g.sorter.request(row);
        };
        go();
      });
    }

    async function benchmark(nFrames) {
      guard();
      await ready;
      if (benchmarking) throw new Error('a benchmark is already running');
      const n = Math.max(1, Math.floor(nFrames || 60));
      benchmarking = true;
      const px = new Uint8Array(4);
      let sortTotal = 0;
      let renderTotal = 0;
      try {
        const t0 = performance.now();
        for (let i = 0; i < n; i++) {
          orbit(2, 0); // about 0.6 degrees a frame
          const a = performance.now();
          const row = depthRow();
          await Promise.all(neededGeoms().map(function (g) { return sortNow(g, row); }));
          const b = performance.now();
          draw();
          gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px); // waits for the GPU
          const c = performance.now();
          sortTotal += b - a;
          renderTotal += c - b;
        }
        const mean = (performance.now() - t0) / n;
        lastBench = { meanMs: mean, sortMs: sortTotal / n, renderMs: renderTotal / n, frames: n };
        S.fps = 1000 / mean;
        return mean;
      } finally {
        benchmarking = false;
        markDirty();
      }
    }
  }

  return { create: create, decodeScene: decodeScene, decodeBase64: decodeBase64, tsSortCore: tsSortCore };
})();

(function () {
  function run() {
    const roots = document.querySelectorAll('.ts-viewer');
    for (let i = 0; i < roots.length; i++) {
      if (!roots[i].tsViewer) transsplatViewer(roots[i]);
    }
  }
  if (document.readyState === 'loading') {
    document.addEventListener('DOMContentLoaded', run);
  } else {
    run();
  }
})();
