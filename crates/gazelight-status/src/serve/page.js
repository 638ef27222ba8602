// gazelight status page: plain JS, no dependencies. Shows the status and
// history the server put into the page (#initial) at once, then follows
// the WebSocket /ws (status JSON, ~10 Hz); /api/history only when the page
// came without them.
// Errors are caught into #errors (and body[data-errors]) so a headless
// test can see them; the newest status is mirrored into #state.
"use strict";

(function () {
  const MAX_POINTS = 2000;
  const errorsEl = document.getElementById("errors");
  let errorCount = 0;
  function reportError(msg) {
    errorCount += 1;
    document.body.dataset.errors = String(errorCount);
    errorsEl.textContent += msg + "\n";
  }
  window.addEventListener("error", (e) => reportError("error: " + e.message));
  window.addEventListener("unhandledrejection", (e) => reportError("unhandled rejection: " + e.reason));

  const hist = { t: [], r: [], l: [], a: [], al: [], ar: [], pr: [], pl: [] };
  let stereo = false;
  let updates = 0;
  let lastFrameT = null;
  let lastPsf = 0;
  let lastFrameImgAt = 0;

  function push(t, r, l, a, al, ar, pr, pl) {
    if (lastFrameT !== null && t <= lastFrameT) return;
    lastFrameT = t;
    hist.t.push(t); hist.r.push(r); hist.l.push(l); hist.a.push(a);
    hist.al.push(al === undefined ? null : al); hist.ar.push(ar === undefined ? null : ar);
    hist.pr.push(pr === undefined ? null : pr); hist.pl.push(pl === undefined ? null : pl);
    if (hist.t.length > MAX_POINTS) {
      for (const k of Object.keys(hist)) hist[k].shift();
    }
  }

  const fmt = (v, d, unit) => (v === null || v === undefined || !isFinite(v)) ? "–" : v.toFixed(d) + (unit ? " " + unit : "");
  const set = (id, text) => { document.getElementById(id).textContent = text; };

  function plot(canvas, series, opts) {
    const ctx = canvas.getContext("2d");
    const w = canvas.width, h = canvas.height, pad = 34;
    ctx.clearRect(0, 0, w, h);
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillStyle = "#8b96a3";
    const t = hist.t;
    if (t.length < 2) { ctx.fillText("waiting for frames…", pad, h / 2); return; }
    let lo = Infinity, hi = -Infinity;
    for (const s of series) for (const v of s.data) {
      if (v === null) continue;
      const y = opts.log ? Math.log10(Math.max(v, 1e-6)) : v;
      if (isFinite(y)) { lo = Math.min(lo, y); hi = Math.max(hi, y); }
    }
    if (!isFinite(lo)) return;
    if (hi - lo < opts.minSpan) { const m = (hi + lo) / 2; lo = m - opts.minSpan / 2; hi = m + opts.minSpan / 2; }
    const t0 = t[0], t1 = t[t.length - 1];
    const X = (x) => pad + (x - t0) / Math.max(t1 - t0, 1e-9) * (w - pad - 6);
    const Y = (y) => h - 14 - (y - lo) / (hi - lo) * (h - 24);
    ctx.strokeStyle = "#2a313a";
    ctx.beginPath(); ctx.moveTo(pad, 6); ctx.lineTo(pad, h - 14); ctx.lineTo(w - 6, h - 14); ctx.stroke();
    const label = (y) => opts.log ? Math.pow(10, y).toPrecision(2) : y.toFixed(2);
    ctx.fillText(label(hi), 2, 14); ctx.fillText(label(lo), 2, h - 16);
    ctx.fillText((t1 - t0).toFixed(1) + " s", w - 46, h - 2);
    for (const s of series) {
      ctx.strokeStyle = s.color; ctx.lineWidth = 1.5; ctx.setLineDash(s.dash || []); ctx.beginPath();
      let started = false;
      for (let i = 0; i < t.length; i++) {
        const d = s.data[i];
        const v = d === null ? NaN : (opts.log ? Math.log10(Math.max(d, 1e-6)) : d);
        if (!isFinite(v)) { started = false; continue; }
        if (started) ctx.lineTo(X(t[i]), Y(v)); else { ctx.moveTo(X(t[i]), Y(v)); started = true; }
      }
      ctx.stroke();
    }
  }

  function redraw() {
    plot(document.getElementById("plot-pupil"), [
      { data: hist.r, color: "#5aa9e6" }, { data: hist.l, color: "#e6a15a" },
      { data: hist.pr, color: "#5aa9e6", dash: [4, 3] }, { data: hist.pl, color: "#e6a15a", dash: [4, 3] }], { log: false, minSpan: 0.5 });
    const adapt = stereo
      ? [{ data: hist.ar, color: "#5aa9e6" }, { data: hist.al, color: "#e6a15a" }]
      : [{ data: hist.a, color: "#b8e65a" }];
    plot(document.getElementById("plot-adapt"), adapt, { log: true, minSpan: 0.2 });
  }

  // One value per eye, "right / left".
  const perEye = (v, f) => f(v[0]) + " / " + f(v[1]);
  const pct = (v) => (v === null || v === undefined) ? "–" : fmt(v * 100, 1, "%");

  // `fromSocket`: a WebSocket update (counted), not the page's initial state.
  function apply(s, fromSocket) {
    if (fromSocket) {
      updates += 1;
      document.body.dataset.updates = String(updates);
      set("updates", String(updates));
    }
    const src = s.source, eye = s.eye, fr = s.frame, tm = fr.timings;
    set("source-uri", src.uri);
    set("source-health", src.health);
    set("sample-rate", fmt(src.sample_rate_hz, 1, "Hz"));
    set("eye-rate", perEye(src.eye_rate_hz || [null, null], (v) => fmt(v, 1, "Hz")));
    set("confidence", fmt(src.confidence, 3));
    set("dropout", perEye(src.eye_dropout_rate || [null, null], pct));
    set("streams", (src.streams || []).map((x) =>
      x.name + ": " + fmt(x.rate_hz, 0, "Hz") +
      (x.dropout_rate === null ? (x.uncalibrated > 0 ? ", no calibration" : "") : ", " + pct(x.dropout_rate))).join("\n") || "–");
    if ((fr.views === 2) !== stereo) {
      stereo = fr.views === 2;
      document.getElementById("adapt-legend").innerHTML = stereo
        ? '<span class="r">■ right</span><span class="l">■ left</span>'
        : '<span class="a">■ adaptation</span>';
    }
    set("samples", src.samples_total + " / " + src.samples_dropped);
    // The measured pupil (mm, or the tracker's raw unit) and, apart, the
    // model aperture the glare PSF is built for.
    const units = { px: "px", arbitrary_area: "area units", arbitrary: "raw units", mm: "mm" };
    const measured = (k) => eye.measured[k] === null ? "not measured"
      : fmt(eye.measured[k], eye.measured_unit[k] === "mm" ? 3 : 1, units[eye.measured_unit[k]] || "");
    set("pupil-right", measured(0) + "; aperture " + fmt(eye.aperture_mm[0], 2, "mm") + " (" + eye.pupil_origin[0] + ")");
    set("pupil-left", measured(1) + "; aperture " + fmt(eye.aperture_mm[1], 2, "mm") + " (" + eye.pupil_origin[1] + ")");
    set("gaze", fmt(eye.gaze_uv[0], 3) + ", " + fmt(eye.gaze_uv[1], 3) + (eye.gaze_valid ? "" : " (invalid)"));
    set("eye-age", fmt(eye.age_ms, 1, "ms"));
    const ck = src.clock;
    set("clock", ck ? ck.jumps + " / " + (ck.rejected + ck.non_finite) +
      (ck.last_jump_secs === null ? "" : " (last " + fmt(ck.last_jump_secs, 3, "s") + ")") : "–");
    set("degraded", src.degraded_reason || "–");
    set("last-error", src.last_error || "–");
    set("frames", fr.frames + " / " + fr.frames_late);
    set("adaptation", fmt(fr.adaptation_cd_m2, 4, "cd/m²"));
    set("target", fmt(fr.target_cd_m2, 4, "cd/m²"));
    set("frame-pupil", fmt(fr.frame_pupil_mm, 3, "mm"));
    set("frame-age", fmt(fr.eye_state_age_ms, 2, "ms"));
    set("frame-ms", fmt(fr.frame_ms, 2, "ms"));
    const pt = fr.parts || {};
    set("p-render", fmt(pt.stages_ms, 2) + " + " + fmt(pt.render_other_ms, 2) + " ms");
    set("p-prep", fmt(pt.prepare_ms, 2) + " / " + fmt(pt.view_ms, 2) + " / " + fmt(pt.psf_install_ms, 2) + " ms");
    set("p-present", fmt(pt.pupil_light_ms, 2) + " / " + fmt(pt.present_ms, 2) + " ms");
    set("t-pool", fmt(tm.pooling_ms, 2) + " / " + fmt(tm.temporal_ms, 2) + " ms");
    set("t-glare", fmt(tm.psf_ms, 2) + " / " + fmt(tm.glare_ms, 2) + " ms");
    set("t-tone", fmt(tm.acuity_ms, 2) + " / " + fmt(tm.tone_colour_encode_ms, 2) + " ms");
    set("psf-rebuilds", String(fr.psf_rebuilds));
    const va = fr.view_adaptation_cd_m2 || [null, null];
    const light = fr.pupil_light_mm || [null, null], residual = fr.pupil_residual_mm || [null, null];
    set("pupil-light", perEye(light, (v) => fmt(v, 3, "mm")));
    set("pupil-residual", perEye(residual, (v) => fmt(v, 3, "mm")));
    document.getElementById("state").textContent = JSON.stringify({
      updates: updates, now_secs: s.now_secs, frames: fr.frames,
      adaptation_cd_m2: fr.adaptation_cd_m2, pupil_mm: eye.pupil_mm,
      eye_updates: eye.updates, health: src.health, psf_rebuild: s.psf.rebuild,
      clock_jumps: src.clock ? src.clock.jumps : null,
      eye_rate_hz: src.eye_rate_hz, eye_dropout_rate: src.eye_dropout_rate,
      pupil_light: document.getElementById("pupil-light").textContent,
      shown: { eye_rate: document.getElementById("eye-rate").textContent,
               dropout: document.getElementById("dropout").textContent },
    });
    if (fr.frames > 0) push(fr.t_secs, fr.pupil_mm[0], fr.pupil_mm[1], fr.adaptation_cd_m2, va[0], va[1], light[0], light[1]);
    if (s.psf.rebuild > 0 && s.psf.rebuild !== lastPsf) {
      lastPsf = s.psf.rebuild;
      document.getElementById("psf").src = "/psf.png?rebuild=" + lastPsf;
      set("psf-caption", "PSF #" + lastPsf + " at " + fmt(s.psf.pupil_mm, 2, "mm") + ", " + s.psf.size_px + " px, log");
    }
    const now = Date.now();
    if (s.display.frame > 0 && now - lastFrameImgAt > 1000) {
      lastFrameImgAt = now;
      document.getElementById("frame").src = "/frame.png?frame=" + s.display.frame;
      set("frame-caption", "frame " + s.display.frame + " (" + s.display.width + "×" + s.display.height + ")");
    }
    redraw();
  }

  function seedFrom(h) {
    const al = h.adaptation_left_cd_m2 || [], ar = h.adaptation_right_cd_m2 || [];
    const pr = h.pupil_light_right_mm || [], pl = h.pupil_light_left_mm || [];
    for (let i = 0; i < h.t_secs.length; i++) push(h.t_secs[i], h.pupil_right_mm[i], h.pupil_left_mm[i], h.adaptation_cd_m2[i], al[i], ar[i], pr[i], pl[i]);
  }

  async function seed() {
    const r = await fetch("/api/history", { cache: "no-store" });
    if (!r.ok) throw new Error("/api/history: HTTP " + r.status);
    seedFrom(await r.json());
    redraw();
  }

  // The state the server put into the page: shown before any update.
  function initial() {
    const el = document.getElementById("initial");
    let init = null;
    try { init = JSON.parse(el.textContent); } catch (e) { return false; }
    if (!init || !init.status || !init.history) return false;
    seedFrom(init.history);
    apply(init.status, false);
    const conn = document.getElementById("conn");
    conn.textContent = "connecting… (showing the state at load)";
    return true;
  }

  function connect() {
    const conn = document.getElementById("conn");
    const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
    ws.onopen = () => { conn.textContent = "live"; conn.className = "live"; };
    ws.onmessage = (ev) => {
      try { apply(JSON.parse(ev.data), true); } catch (e) { reportError("status update: " + e); }
    };
    ws.onclose = () => {
      conn.textContent = "disconnected — retrying"; conn.className = "down";
      setTimeout(connect, 1000);
    };
  }

  if (initial()) connect();
  else seed().catch((e) => reportError("history: " + e)).finally(connect);
})();
