"use strict";
// Prism's slice viewer. window.PRISM_SETS lists the sets ([{title, file}]); each file is a
// script beside the page that calls PrismViewer.add(index, data) with what
// prism_experiment::html::slices writes: shape [nz, ny, nx], the kept slices and the atlas
// columns; per channel the level range (lo, top), the default window top (hi), the residual
// range (rmax) and the reference atlas; per method its scores and its image and residual atlases
// (8-bit PNG data URLs; slice k in tile k, tiles left to right then top to bottom).
const PrismViewer = (() => {
  const sets = window.PRISM_SETS || [];
  const decoded = new Map();
  const waiting = new Map();
  const state = { set: 0, channel: 0, k: 0, lo: 0, hi: 255, residual: false, rscale: 100, size: 208, hidden: new Set(), cursor: null };
  const $ = (id) => document.getElementById(id);
  let renders = 0;

  // The set scripts call this.
  function add(index, data) {
    const resolve = waiting.get(index);
    if (resolve) {
      waiting.delete(index);
      resolve(data);
    }
  }

  function fetchSet(index) {
    return new Promise((resolve, reject) => {
      waiting.set(index, resolve);
      const s = document.createElement("script");
      s.src = sets[index].file;
      s.onerror = () => {
        waiting.delete(index);
        reject(new Error(`cannot read ${sets[index].file}: keep that folder beside the page`));
      };
      document.head.appendChild(s);
    });
  }

  // The levels of an 8-bit grey PNG, exactly (no colour management, no premultiplication).
  async function levels(url) {
    if (!url) return null;
    const img = new Image();
    img.src = url;
    await img.decode();
    const bmp = await createImageBitmap(img, { colorSpaceConversion: "none", premultiplyAlpha: "none" });
    const canvas = document.createElement("canvas");
    canvas.width = bmp.width;
    canvas.height = bmp.height;
    const g = canvas.getContext("2d", { willReadFrequently: true });
    g.drawImage(bmp, 0, 0);
    const rgba = g.getImageData(0, 0, bmp.width, bmp.height).data;
    const px = new Uint8Array(bmp.width * bmp.height);
    for (let p = 0; p < px.length; p++) px[p] = rgba[4 * p];
    return { width: bmp.width, px };
  }

  async function load(index) {
    if (decoded.has(index)) return decoded.get(index);
    const d = await fetchSet(index);
    for (const c of d.channels) c.ref = await levels(c.reference);
    for (const m of d.methods) {
      m.img = await Promise.all(m.images.map(levels));
      m.res = await Promise.all(m.residuals.map(levels));
    }
    decoded.set(index, d);
    return d;
  }

  // Level q of channel c in mm⁻¹, and the level of value v.
  const value = (c, q) => c.lo + (q / 255) * (c.top - c.lo);
  const level = (c, v) => Math.round((255 * (v - c.lo)) / (c.top - c.lo));
  const residual = (c, q) => ((q - 128) / 127) * c.rmax;
  const fmt = (v) => (Math.abs(v) >= 0.01 || v === 0 ? v.toFixed(4) : v.toExponential(2));

  function defaultWindow(c) {
    state.lo = Math.max(0, level(c, 0));
    state.hi = Math.min(255, level(c, c.hi));
  }

  function colours() {
    const lo = state.lo;
    const hi = Math.max(state.hi, lo + 1);
    const grey = [];
    for (let q = 0; q < 256; q++) {
      const g = Math.round(255 * Math.min(1, Math.max(0, (q - lo) / (hi - lo))));
      grey.push([g, g, g]);
    }
    const frac = state.rscale / 100;
    const diverging = [];
    for (let q = 0; q < 256; q++) {
      let t = Math.max(-1, Math.min(1, (q - 128) / 127 / frac));
      const end = t < 0 ? [33, 102, 172] : [178, 24, 43];
      t = Math.abs(t);
      diverging.push(end.map((e) => Math.round(255 + (e - 255) * t)));
    }
    return { grey, diverging };
  }

  // The panels of the current set and channel: the reference, then every method shown.
  function panels(d) {
    const c = d.channels[state.channel];
    const list = [];
    if (c.ref) list.push({ label: "reference", atlas: c.ref, kind: "image", score: null });
    d.methods.forEach((m, i) => {
      if (state.hidden.has(i)) return;
      const showResidual = state.residual && m.res[state.channel];
      list.push({
        label: showResidual ? `${m.label} − reference` : m.label,
        atlas: showResidual ? m.res[state.channel] : m.img[state.channel],
        kind: showResidual ? "residual" : "image",
        score: m.scores[state.channel],
      });
    });
    return list;
  }

  function build() {
    const d = decoded.get(state.set);
    const root = $("pv-panels");
    root.replaceChildren();
    const [, ny, nx] = d.shape;
    const list = panels(d);
    for (const p of list) {
      const fig = document.createElement("figure");
      fig.className = "panel";
      const canvas = document.createElement("canvas");
      canvas.width = nx;
      canvas.height = ny;
      canvas.style.width = `${Math.round((state.size * nx) / Math.max(nx, ny))}px`;
      canvas.setAttribute("aria-label", p.label);
      const cap = document.createElement("figcaption");
      const name = document.createElement("div");
      name.textContent = p.label;
      cap.append(name);
      if (p.score) {
        const s = document.createElement("div");
        s.textContent = `PSNR ${p.score.psnr.toFixed(2)} dB` + (p.score.ssim == null ? "" : `, SSIM ${p.score.ssim.toFixed(3)}`);
        cap.append(s);
      }
      const v = document.createElement("div");
      v.className = "value";
      v.textContent = "\u00a0";
      cap.append(v);
      fig.append(canvas, cap);
      root.append(fig);
      p.canvas = canvas;
      p.value = v;
      canvas.addEventListener("mousemove", (e) => {
        const r = canvas.getBoundingClientRect();
        state.cursor = {
          x: Math.min(nx - 1, Math.floor(((e.clientX - r.left) / r.width) * nx)),
          y: Math.min(ny - 1, Math.floor(((e.clientY - r.top) / r.height) * ny)),
        };
        render();
      });
      canvas.addEventListener("mouseleave", () => {
        state.cursor = null;
        render();
      });
      canvas.addEventListener(
        "wheel",
        (e) => {
          e.preventDefault();
          setSlice(state.k + (e.deltaY > 0 ? 1 : -1));
        },
        { passive: false },
      );
    }
    d.shown = list;
  }

  function render() {
    const d = decoded.get(state.set);
    if (!d) return;
    const [nz, ny, nx] = d.shape;
    const c = d.channels[state.channel];
    const map = colours();
    const tx = state.k % d.cols;
    const ty = Math.floor(state.k / d.cols);
    for (const p of d.shown) {
      const g = p.canvas.getContext("2d");
      const img = g.createImageData(nx, ny);
      const lut = p.kind === "residual" ? map.diverging : map.grey;
      for (let y = 0; y < ny; y++) {
        const row = (ty * ny + y) * p.atlas.width + tx * nx;
        for (let x = 0; x < nx; x++) {
          const rgb = lut[p.atlas.px[row + x]];
          const o = 4 * (y * nx + x);
          img.data[o] = rgb[0];
          img.data[o + 1] = rgb[1];
          img.data[o + 2] = rgb[2];
          img.data[o + 3] = 255;
        }
      }
      g.putImageData(img, 0, 0);
      if (state.cursor) {
        const { x, y } = state.cursor;
        const q = p.atlas.px[(ty * ny + y) * p.atlas.width + tx * nx + x];
        const v = p.kind === "residual" ? residual(c, q) : value(c, q);
        p.value.textContent = `(${x}, ${y}): ${fmt(v)} mm⁻¹`;
        g.strokeStyle = "rgba(255, 196, 0, 0.9)";
        g.lineWidth = Math.max(0.5, nx / 256);
        g.strokeRect(x - 1.5, y - 1.5, 4, 4);
      } else {
        p.value.textContent = "\u00a0";
      }
    }
    $("pv-z-label").value = `z = ${d.slices[state.k]} of ${nz}` + (d.slices.length > 1 && d.slices.length < nz ? ` (every ${d.slices[1] - d.slices[0]}th slice kept)` : "");
    $("pv-lo-label").value = `${fmt(value(c, state.lo))} mm⁻¹`;
    $("pv-hi-label").value = `${fmt(value(c, state.hi))} mm⁻¹`;
    $("pv-rscale-label").value = `± ${fmt((c.rmax * state.rscale) / 100)} mm⁻¹`;
    renders += 1;
    document.body.dataset.renders = String(renders);
  }

  function setSlice(k) {
    const d = decoded.get(state.set);
    state.k = Math.max(0, Math.min(d.slices.length - 1, k));
    $("pv-z").value = String(state.k);
    render();
  }

  function controls(d) {
    const chans = $("pv-channels");
    chans.replaceChildren();
    d.channels.forEach((c, i) => {
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = c.label;
      b.setAttribute("role", "radio");
      b.setAttribute("aria-checked", String(i === state.channel));
      b.addEventListener("click", () => {
        state.channel = i;
        for (const o of chans.children) o.setAttribute("aria-checked", String(o === b));
        build();
        render();
      });
      chans.append(b);
    });
    const meths = $("pv-methods");
    meths.replaceChildren();
    d.methods.forEach((m, i) => {
      const l = document.createElement("label");
      const box = document.createElement("input");
      box.type = "checkbox";
      box.checked = !state.hidden.has(i);
      box.addEventListener("change", () => {
        if (box.checked) state.hidden.delete(i);
        else state.hidden.add(i);
        build();
        render();
      });
      l.append(box, ` ${m.label}`);
      meths.append(l);
    });
    const z = $("pv-z");
    z.max = String(d.slices.length - 1);
    z.disabled = d.slices.length < 2;
    z.value = String(state.k);
    $("pv-residual").disabled = !d.channels.some((c) => c.ref);
    $("pv-lo").value = String(state.lo);
    $("pv-hi").value = String(state.hi);
    const notes = $("pv-notes");
    notes.replaceChildren(...d.notes.map((n) => Object.assign(document.createElement("li"), { textContent: n })));
  }

  async function show(index) {
    state.set = index;
    $("pv-status").textContent = `loading ${sets[index].title}…`;
    try {
      const d = await load(index);
      if (state.set !== index) return;
      state.channel = Math.min(state.channel, d.channels.length - 1);
      state.k = Math.floor(d.slices.length / 2);
      state.hidden.clear();
      defaultWindow(d.channels[state.channel]);
      controls(d);
      build();
      render();
      $("pv-status").textContent = "";
      document.body.dataset.viewer = "ready";
    } catch (e) {
      $("pv-status").textContent = String(e.message || e);
      console.error(e);
    }
  }

  function start() {
    if (!sets.length) return;
    const select = $("pv-set");
    sets.forEach((s, i) => select.append(new Option(s.title, String(i))));
    select.addEventListener("change", () => show(Number(select.value)));
    $("pv-z").addEventListener("input", (e) => setSlice(Number(e.target.value)));
    for (const id of ["pv-lo", "pv-hi"]) {
      $(id).addEventListener("input", () => {
        state.lo = Number($("pv-lo").value);
        state.hi = Number($("pv-hi").value);
        render();
      });
    }
    $("pv-auto").addEventListener("click", () => {
      const d = decoded.get(state.set);
      if (!d) return;
      defaultWindow(d.channels[state.channel]);
      $("pv-lo").value = String(state.lo);
      $("pv-hi").value = String(state.hi);
      render();
    });
    $("pv-residual").addEventListener("change", (e) => {
      state.residual = e.target.checked;
      build();
      render();
    });
    $("pv-size").addEventListener("input", (e) => {
      state.size = Number(e.target.value);
      if (!decoded.has(state.set)) return;
      build();
      render();
    });
    $("pv-rscale").addEventListener("input", (e) => {
      state.rscale = Number(e.target.value);
      render();
    });
    show(0);
  }

  document.addEventListener("DOMContentLoaded", start);
  return { add };
})();
