// grip-bench viewer page (grip_bench/report/viewer.py writes the data this decodes).
// Everything is inline: no network, works from file://. Uses window.THREE (three.js r170).
(function () {
  "use strict";
  const T = window.THREE;
  const meta = JSON.parse(document.getElementById("gb-meta").textContent);
  const $ = (id) => document.getElementById(id);
  const BASE = [0xd9a07e, 0x5b8fd9, 0x6cbf6a, 0xb07ad9, 0xd9c45b, 0x5bcfd0];
  const PEN = new T.Color(0xd7301f), TOUCH = new T.Color(0xffb000);
  const NEAR = 0.02; // m: colour fades from contact to the base colour up to here

  function fail(msg) {
    $("status").textContent = msg;
    console.error("grip-bench viewer: " + msg);
  }

  // --- data ------------------------------------------------------------------------------
  async function inflate() {
    const b64 = document.getElementById("gb-data").textContent.trim();
    const bin = atob(b64), raw = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) raw[i] = bin.charCodeAt(i);
    if (typeof DecompressionStream === "undefined") {
      throw new Error("this browser lacks DecompressionStream (needs Chrome 80+, Firefox 113+, Safari 16.4+)");
    }
    const stream = new Blob([raw]).stream().pipeThrough(new DecompressionStream("gzip"));
    return new Response(stream).arrayBuffer();
  }

  const decoded = {};

  function view(buf, name) {
    if (decoded[name]) return decoded[name];
    const a = meta.arrays[name], n = a.shape.reduce((x, y) => x * y, 1);
    let out;
    if (a.coding) out = series(new Uint8Array(buf, a.offset, a.length), a);
    else if (a.dtype === "f32") out = new Float32Array(buf, a.offset, n);
    else if (a.dtype === "u16") out = new Uint16Array(buf, a.offset, n);
    else if (a.dtype === "u32") out = new Uint32Array(buf, a.offset, n);
    else throw new Error("unknown array " + name);
    decoded[name] = out;
    return out;
  }

  // A (T, N) series stored coordinate-major (N, T): temporal residuals of order 0-2 of the
  // values or of their difference to a reference array; int16 as low / high byte planes.
  // Typed-array stores wrap (mod 2^16 / 2^8), as the Python encoder's casts do.
  // Returns the (N, T) values: coordinate k at frame f is out[k * T + f].
  function series(bytes, a) {
    const nt = a.shape[0], n = a.shape[1], all = nt * n;
    const out = a.dtype === "u8" ? new Uint8Array(all) : new Int16Array(all);
    if (a.dtype === "u8") out.set(bytes.subarray(0, all));
    else for (let i = 0; i < all; i++) out[i] = bytes[i] | (bytes[all + i] << 8);
    const order = a.coding.order;
    for (let k = 0; k < n && order > 0; k++) {
      const o = k * nt;
      for (let t = 1; t < nt; t++) {
        out[o + t] = order === 1 || t === 1 ? out[o + t] + out[o + t - 1]
          : out[o + t] + 2 * out[o + t - 1] - out[o + t - 2];
      }
    }
    if (a.coding.ref) {
      const ref = decoded[a.coding.ref];
      for (let i = 0; i < all; i++) out[i] = out[i] + ref[i];
    }
    return out;
  }

  // --- scene -----------------------------------------------------------------------------
  function build(buf) {
    const scene = new T.Scene();
    scene.background = new T.Color(0xf4f4f4);
    scene.add(new T.HemisphereLight(0xffffff, 0x888888, 1.6));
    const sun = new T.DirectionalLight(0xffffff, 1.6);
    scene.add(sun);
    const objGeom = new T.BufferGeometry();
    objGeom.setAttribute("position", new T.BufferAttribute(view(buf, "object_vertices"), 3));
    objGeom.setIndex(new T.BufferAttribute(view(buf, "object_faces"), 1));
    objGeom.computeVertexNormals();
    const faces = {};
    const tracks = meta.tracks.map((tr, i) => {
      const group = new T.Group();
      const objMat = new T.MeshStandardMaterial({color: 0x9a9a9a, roughness: 0.7,
        transparent: !tr.reference, opacity: 1});
      const obj = new T.Mesh(objGeom, objMat);
      obj.matrixAutoUpdate = false;
      group.add(obj);
      const base = new T.Color(BASE[i % BASE.length]);
      const hands = {};
      for (const side of ["right", "left"]) {
        const h = tr.hands[side];
        if (!faces[h.faces]) faces[h.faces] = new T.BufferAttribute(view(buf, h.faces), 1);
        const g = new T.BufferGeometry();
        g.setAttribute("position", new T.BufferAttribute(new Float32Array(h.n_vertices * 3), 3));
        g.setAttribute("color", new T.BufferAttribute(new Float32Array(h.n_vertices * 3), 3));
        g.setIndex(faces[h.faces]);
        const mat = new T.MeshStandardMaterial({vertexColors: true, roughness: 0.6,
          side: T.DoubleSide, transparent: true, opacity: 1});
        const mesh = new T.Mesh(g, mat);
        mesh.frustumCulled = false;
        group.add(mesh);
        hands[side] = {mesh, n: h.n_vertices, pos: view(buf, h.positions),
          contact: view(buf, h.contact)};
      }
      const pose = view(buf, tr.object_pose);
      scene.add(group);
      return {tr, group, obj, hands, pose, base};
    });
    return {scene, sun, tracks};
  }

  function colour(out, k, code, base) {
    const d = meta.contact.min + code * meta.contact.step;
    let c;
    if (d < 0) c = PEN;
    else if (d < meta.contact.threshold) c = TOUCH;
    else if (d < NEAR) {
      const s = (d - meta.contact.threshold) / (NEAR - meta.contact.threshold);
      out[k] = TOUCH.r + (base.r - TOUCH.r) * s;
      out[k + 1] = TOUCH.g + (base.g - TOUCH.g) * s;
      out[k + 2] = TOUCH.b + (base.b - TOUCH.b) * s;
      return;
    } else c = base;
    out[k] = c.r; out[k + 1] = c.g; out[k + 2] = c.b;
  }

  function setFrame(world, f) {
    const lo = meta.box.lo, step = meta.box.step;
    for (const t of world.tracks) {
      const p = t.pose, o = f * 12, m = new T.Matrix4();
      // row-vector pose world = local @ R + t  ->  column matrix R^T
      m.set(p[o], p[o + 3], p[o + 6], p[o + 9],
            p[o + 1], p[o + 4], p[o + 7], p[o + 10],
            p[o + 2], p[o + 5], p[o + 8], p[o + 11],
            0, 0, 0, 1);
      t.obj.matrix.copy(m);
      t.obj.matrixWorldNeedsUpdate = true;
      for (const side of ["right", "left"]) {
        const h = t.hands[side], n3 = h.n * 3, nt = meta.frames.length;
        const pos = h.mesh.geometry.attributes.position, col = h.mesh.geometry.attributes.color;
        for (let k = 0; k < n3; k++) pos.array[k] = lo[k % 3] + (h.pos[k * nt + f] + 32767) * step;
        for (let v = 0; v < h.n; v++) colour(col.array, 3 * v, h.contact[v * nt + f], t.base);
        pos.needsUpdate = true;
        col.needsUpdate = true;
        h.mesh.geometry.computeVertexNormals();
      }
    }
  }

  // --- orbit camera (drag: orbit, wheel: zoom) -------------------------------------------
  function orbit(camera, canvas, render) {
    const up = new T.Vector3().fromArray(meta.up).normalize();
    const a = Math.abs(up.y) > 0.9 ? new T.Vector3(0, 0, 1) : new T.Vector3(0, -1, 0);
    const b = new T.Vector3().crossVectors(up, a);
    const st = {az: 0.5, el: 0.45, r: 1, drag: null};
    camera.up.copy(up);
    const target = new T.Vector3().fromArray(meta.centre);
    // fit the bounding sphere into one side-by-side viewport (the narrower view)
    const canvasAspect = canvas.clientWidth / Math.max(1, canvas.clientHeight);
    const aspect = meta.overlay ? canvasAspect : canvasAspect / meta.tracks.length;
    const half = Math.min(T.MathUtils.degToRad(camera.fov) / 2,
      Math.atan(Math.tan(T.MathUtils.degToRad(camera.fov) / 2) * aspect));
    st.r = Math.max(0.05, (meta.radius / Math.sin(half)) * 1.02);
    function place() {
      const dir = a.clone().multiplyScalar(Math.cos(st.el) * Math.cos(st.az))
        .addScaledVector(b, Math.cos(st.el) * Math.sin(st.az))
        .addScaledVector(up, Math.sin(st.el));
      camera.position.copy(target).addScaledVector(dir, st.r);
      camera.near = st.r / 100; camera.far = st.r * 100;
      camera.lookAt(target);
      camera.updateProjectionMatrix();
    }
    canvas.addEventListener("pointerdown", (e) => {
      st.drag = [e.clientX, e.clientY];
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", (e) => {
      if (!st.drag) return;
      st.az -= (e.clientX - st.drag[0]) * 0.01;
      st.el = Math.max(-1.5, Math.min(1.5, st.el + (e.clientY - st.drag[1]) * 0.01));
      st.drag = [e.clientX, e.clientY];
      place(); render();
    });
    canvas.addEventListener("pointerup", () => { st.drag = null; });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      st.r = Math.max(0.02, Math.min(50, st.r * Math.exp(e.deltaY * 0.001)));
      place(); render();
    }, {passive: false});
    place();
    return place;
  }

  // --- metric panel ----------------------------------------------------------------------
  function fmt(v) {
    if (v === null || v === undefined) return "–";
    if (Number.isInteger(v)) return String(v);
    return Math.abs(v) >= 100 ? v.toFixed(0) : v.toFixed(2);
  }

  function metricPanel(world) {
    const names = [];
    for (const t of meta.tracks) {
      for (const k of Object.keys(t.frame_metrics)) if (!names.includes(k)) names.push(k);
    }
    const seqNames = [];
    for (const t of meta.tracks) {
      for (const k of Object.keys(t.sequence_metrics)) if (!seqNames.includes(k)) seqNames.push(k);
    }
    const table = $("metrics");
    const head = document.createElement("tr");
    head.appendChild(document.createElement("th"));
    world.tracks.forEach((t) => {
      const th = document.createElement("th");
      const sw = document.createElement("span");
      sw.className = "sw";
      sw.style.background = "#" + t.base.getHexString();
      th.appendChild(sw);
      th.appendChild(document.createTextNode(t.tr.label));
      head.appendChild(th);
    });
    table.appendChild(head);
    const cells = [];
    function row(label, cls) {
      const tr = document.createElement("tr");
      const th = document.createElement("td");
      th.textContent = label;
      if (cls) tr.className = cls;
      tr.appendChild(th);
      const tds = meta.tracks.map(() => {
        const td = document.createElement("td");
        tr.appendChild(td);
        return td;
      });
      table.appendChild(tr);
      return tds;
    }
    if (names.length) row("this frame", "section");
    for (const k of names) cells.push([k, row(k), "frame"]);
    if (seqNames.length) row("whole sequence", "section");
    for (const k of seqNames) {
      const tds = row(k);
      meta.tracks.forEach((t, i) => { tds[i].textContent = fmt(t.sequence_metrics[k]); });
    }
    return function update(f) {
      for (const [k, tds] of cells) {
        meta.tracks.forEach((t, i) => {
          const v = t.frame_metrics[k];
          tds[i].textContent = v ? fmt(v[f]) : "–";
        });
      }
    };
  }

  // --- page ------------------------------------------------------------------------------
  async function main() {
    const buf = await inflate();
    const world = build(buf);
    const canvas = $("canvas");
    const renderer = new T.WebGLRenderer({canvas, antialias: true, preserveDrawingBuffer: true});
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setScissorTest(true);
    const camera = new T.PerspectiveCamera(40, 1, 0.01, 100);
    const labels = $("labels");
    const nf = meta.frames.length;
    const state = {frame: 0, playing: false, t: 0, last: 0};
    const updateMetrics = metricPanel(world);
    $("legend").innerHTML = "";
    [["penetrating the object", PEN], [`within ${(meta.contact.threshold * 1000).toFixed(1)} mm (contact)`, TOUCH]]
      .forEach(([text, c]) => {
        const d = document.createElement("div");
        const sw = document.createElement("span");
        sw.className = "sw"; sw.style.background = "#" + c.getHexString();
        d.appendChild(sw); d.appendChild(document.createTextNode(text));
        $("legend").appendChild(d);
      });
    const note = document.createElement("div");
    note.textContent = `fading to the track colour at ${NEAR * 1000} mm`;
    $("legend").appendChild(note);

    function overlay() { return $("overlay").checked; }

    function layoutLabels() {
      labels.innerHTML = "";
      const n = overlay() ? 1 : world.tracks.length;
      for (let i = 0; i < n; i++) {
        const d = document.createElement("div");
        d.style.left = `calc(${(100 * i) / n}% + 6px)`;
        d.textContent = overlay() ? world.tracks.map((t) => t.tr.label).join(" + ")
          : world.tracks[i].tr.label;
        labels.appendChild(d);
      }
    }

    function render() {
      const w = canvas.clientWidth, h = canvas.clientHeight;
      if (canvas.width !== Math.floor(w * renderer.getPixelRatio())
          || canvas.height !== Math.floor(h * renderer.getPixelRatio())) {
        renderer.setSize(w, h, false);
      }
      world.sun.position.copy(camera.position);
      if (overlay()) {
        world.tracks.forEach((t, i) => {
          t.group.visible = true;
          t.obj.visible = i === 0 || !meta.same_object;
          for (const s of ["right", "left"]) {
            t.hands[s].mesh.material.opacity = i === 0 ? 1 : 0.6;
            t.hands[s].mesh.material.depthWrite = i === 0;
          }
        });
        camera.aspect = w / h; camera.updateProjectionMatrix();
        renderer.setViewport(0, 0, w, h); renderer.setScissor(0, 0, w, h);
        renderer.render(world.scene, camera);
      } else {
        const n = world.tracks.length, vw = w / n;
        camera.aspect = vw / h; camera.updateProjectionMatrix();
        world.tracks.forEach((t, i) => {
          world.tracks.forEach((o, j) => { o.group.visible = i === j; });
          t.obj.visible = true;
          for (const s of ["right", "left"]) {
            t.hands[s].mesh.material.opacity = 1;
            t.hands[s].mesh.material.depthWrite = true;
          }
          renderer.setViewport(i * vw, 0, vw, h); renderer.setScissor(i * vw, 0, vw, h);
          renderer.render(world.scene, camera);
        });
      }
    }

    function show(f) {
      state.frame = Math.max(0, Math.min(nf - 1, f | 0));
      setFrame(world, state.frame);
      $("frame").value = String(state.frame);
      const src = meta.frames[state.frame];
      $("frameLabel").textContent = `frame ${src} / ${meta.n_source_frames - 1}  ` +
        `(${(src / 30).toFixed(2)} s)`;
      updateMetrics(state.frame);
      render();
    }

    orbit(camera, canvas, render);
    $("frame").addEventListener("input", () => { state.playing = false; setPlay(); show(+$("frame").value); });
    $("overlay").addEventListener("change", () => { layoutLabels(); render(); });
    function setPlay() { $("play").textContent = state.playing ? "pause" : "play"; }
    $("play").addEventListener("click", () => {
      state.playing = !state.playing;
      if (state.playing && state.frame >= nf - 1) show(0);
      state.last = performance.now(); state.t = state.frame;
      setPlay();
    });
    function tick(now) {
      if (state.playing) {
        state.t += ((now - state.last) / 1000) * meta.fps * parseFloat($("speed").value);
        if (state.t >= nf - 1) { state.t = nf - 1; state.playing = false; setPlay(); }
        if ((state.t | 0) !== state.frame) show(state.t | 0);
      }
      state.last = now;
      requestAnimationFrame(tick);
    }
    window.addEventListener("resize", render);
    layoutLabels();
    show(0);
    requestAnimationFrame(tick);
    window.gripViewer = {ready: true, frames: nf, show, render, state};
    document.body.dataset.ready = "1";
  }

  main().catch((e) => fail(e && e.message ? e.message : String(e)));
})();
