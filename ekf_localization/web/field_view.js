// ekf_localization field view: draws the field, the estimate, the truth, the path and the camera
// fixes, and plots the position error and each input's NIS. Live: state over a WebSocket from the
// field_view node. Replay: window.FIELD_VIEW_EMBEDDED (bag_replay --html) and a time slider.
// No dependencies, no build step. The page's state is exposed as window.fieldView (for tests).
"use strict";
(function () {
  const ROBOT_SIZE = 0.4572; // m, an 18 in FTC robot
  const COLORS = { estimate: "#2563eb", truth: "#111827", path: "#eab308", target: "#a21caf",
                   accepted: "#16a34a", gated: "#dc2626", image: "#0ea5e9", wall: "#374151",
                   camera: "#0284c7" };
  const NIS_COLORS = ["#2563eb", "#16a34a", "#dc2626", "#a21caf", "#ea580c", "#0891b2", "#4b5563"];
  const MARGIN = 26; // px around the field for the walls' labels

  const view = {
    field: null, state: null, connected: false, frames: 0, sent: [],
    drawn: { robot: null, truth: null, ellipse: 0, accepted: 0, gated: 0, path: 0, fov: 0, seen: 0 },
    toCanvas: null, toField: null,
  };
  window.fieldView = view;

  const $ = (id) => document.getElementById(id);
  const canvas = $("field");
  const ctx = canvas.getContext("2d");

  function setupHiDpi(c) {
    const ratio = window.devicePixelRatio || 1;
    const w = c.width, h = c.height;
    c.style.width = w + "px"; c.style.height = h + "px";
    c.width = Math.round(w * ratio); c.height = Math.round(h * ratio);
    c.getContext("2d").setTransform(ratio, 0, 0, ratio, 0, 0);
    return { w: w, h: h };
  }
  const fieldSize = setupHiDpi(canvas);
  const errSize = setupHiDpi($("error-plot"));
  const nisSize = setupHiDpi($("nis-plot"));

  // field metres <-> canvas CSS pixels (x right, y up: REP-103 seen from above)
  function scale() { return (fieldSize.w - 2 * MARGIN) / view.field.size; }
  view.toCanvas = function (x, y) {
    const h = view.field.size / 2, k = scale();
    return [MARGIN + (x + h) * k, MARGIN + (h - y) * k];
  };
  view.toField = function (px, py) {
    const h = view.field.size / 2, k = scale();
    return [(px - MARGIN) / k - h, h - (py - MARGIN) / k];
  };

  function poly(points, close) {
    if (!points || points.length === 0) return;
    ctx.beginPath();
    points.forEach(function (p, i) {
      const c = view.toCanvas(p[0], p[1]);
      if (i === 0) ctx.moveTo(c[0], c[1]); else ctx.lineTo(c[0], c[1]);
    });
    if (close) ctx.closePath();
  }

  function drawField() {
    const f = view.field, h = f.size / 2;
    ctx.clearRect(0, 0, fieldSize.w, fieldSize.h);
    ctx.fillStyle = "#e5e7eb";
    ctx.fillRect(0, 0, fieldSize.w, fieldSize.h);
    const a = view.toCanvas(-h, h), b = view.toCanvas(h, -h);
    ctx.fillStyle = "#9ca3af"; // foam tiles
    ctx.fillRect(a[0], a[1], b[0] - a[0], b[1] - a[1]);
    ctx.strokeStyle = "rgba(255,255,255,0.35)";
    ctx.lineWidth = 1;
    for (let v = -h + f.tile; v < h - 1e-6; v += f.tile) {
      poly([[v, -h], [v, h]]); ctx.stroke();
      poly([[-h, v], [h, v]]); ctx.stroke();
    }
    if (f.ramp) {
      const r = f.ramp, p = view.toCanvas(r.x_min, r.y_max), q = view.toCanvas(r.x_max, r.y_min);
      ctx.fillStyle = "rgba(120,53,15,0.28)";
      ctx.fillRect(p[0], p[1], q[0] - p[0], q[1] - p[1]);
      ctx.fillStyle = "#78350f"; ctx.font = "11px system-ui"; ctx.fillText("ramp", p[0] + 4, p[1] + 13);
    }
    ctx.strokeStyle = COLORS.wall; ctx.lineWidth = 4;
    ctx.strokeRect(a[0], a[1], b[0] - a[0], b[1] - a[1]);
    // axes at the centre
    const o = view.toCanvas(0, 0), ex = view.toCanvas(0.3, 0), ey = view.toCanvas(0, 0.3);
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#dc2626"; ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(ex[0], ex[1]); ctx.stroke();
    ctx.strokeStyle = "#16a34a"; ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(ey[0], ey[1]); ctx.stroke();
    ctx.fillStyle = "#374151"; ctx.font = "11px system-ui";
    ctx.fillText("x", ex[0] - 4, ex[1] + 13); ctx.fillText("y", ey[0] - 12, ey[1] + 4);
    // wall images (targets): a thick segment and a tick along their normal
    f.images.forEach(function (im) {
      ctx.strokeStyle = COLORS.image; ctx.lineWidth = 7; ctx.lineCap = "butt";
      poly(im.ends); ctx.stroke();
      const n = [Math.cos(im.facing_yaw), Math.sin(im.facing_yaw)];
      ctx.lineWidth = 2;
      poly([[im.x, im.y], [im.x + 0.12 * n[0], im.y + 0.12 * n[1]]]); ctx.stroke();
      const c = view.toCanvas(im.x - 0.02 * n[0] * 0, im.y);
      ctx.fillStyle = "#0c4a6e"; ctx.font = "11px system-ui"; ctx.textAlign = "center";
      const lx = c[0] - n[0] * 15, ly = c[1] + n[1] * 15 + 4;
      ctx.fillText(im.name, Math.min(Math.max(lx, 40), fieldSize.w - 40), Math.min(Math.max(ly, 12), fieldSize.h - 4));
      ctx.textAlign = "start";
    });
  }

  function drawRobot(p, color, filled) {
    const c = Math.cos(p.yaw), s = Math.sin(p.yaw), r = ROBOT_SIZE / 2;
    const corners = [[r, r], [-r, r], [-r, -r], [r, -r]].map(function (q) {
      return [p.x + c * q[0] - s * q[1], p.y + s * q[0] + c * q[1]];
    });
    poly(corners, true);
    if (filled) { ctx.fillStyle = color + "33"; ctx.fill(); }
    ctx.strokeStyle = color; ctx.lineWidth = filled ? 2.5 : 1.5;
    if (!filled) ctx.setLineDash([5, 4]);
    ctx.stroke(); ctx.setLineDash([]);
    poly([[p.x, p.y], [p.x + c * r * 1.25, p.y + s * r * 1.25]]);
    ctx.lineWidth = 2.5; ctx.stroke();
    const o = view.toCanvas(p.x, p.y);
    ctx.beginPath(); ctx.arc(o[0], o[1], 3, 0, 2 * Math.PI); ctx.fillStyle = color; ctx.fill();
  }

  function dots(points, color, radius, cross) {
    (points || []).forEach(function (p) {
      const c = view.toCanvas(p[0], p[1]);
      ctx.strokeStyle = color; ctx.fillStyle = color; ctx.lineWidth = 2;
      if (cross) {
        ctx.beginPath();
        ctx.moveTo(c[0] - radius, c[1] - radius); ctx.lineTo(c[0] + radius, c[1] + radius);
        ctx.moveTo(c[0] + radius, c[1] - radius); ctx.lineTo(c[0] - radius, c[1] + radius);
        ctx.stroke();
      } else {
        ctx.beginPath(); ctx.arc(c[0], c[1], radius, 0, 2 * Math.PI); ctx.globalAlpha = 0.75; ctx.fill();
        ctx.globalAlpha = 1;
      }
    });
  }

  function drawState(st) {
    drawField();
    const d = { robot: null, truth: null, ellipse: 0, accepted: 0, gated: 0, path: 0, fov: 0, seen: 0 };
    if (st.path && st.path.length) {
      ctx.strokeStyle = COLORS.path; ctx.lineWidth = 3; ctx.lineJoin = "round";
      poly(st.path); ctx.stroke();
      d.path = st.path.length;
    }
    const cam = st.camera;
    if (cam && cam.fov && cam.fov.length === 3) { // tag_localizer's field of view on the floor
      poly(cam.fov, true); ctx.fillStyle = "rgba(2,132,199,0.10)"; ctx.fill();
      ctx.strokeStyle = COLORS.camera; ctx.lineWidth = 1; ctx.setLineDash([4, 3]); ctx.stroke(); ctx.setLineDash([]);
      d.fov = cam.fov.length;
    }
    if (cam && cam.seen) { // the tags in its newest image: a ring on each
      cam.seen.forEach(function (p) {
        const c = view.toCanvas(p[0], p[1]);
        ctx.beginPath(); ctx.arc(c[0], c[1], 9, 0, 2 * Math.PI);
        ctx.strokeStyle = COLORS.camera; ctx.lineWidth = 3; ctx.stroke();
      });
      d.seen = cam.seen.length;
    }
    const fixes = st.fixes || { accepted: [], gated: [] };
    dots(fixes.accepted, COLORS.accepted, 4, false);
    dots(fixes.gated, COLORS.gated, 5, true);
    d.accepted = (fixes.accepted || []).length; d.gated = (fixes.gated || []).length;
    if (st.truth) { drawRobot(st.truth, COLORS.truth, false); d.truth = [st.truth.x, st.truth.y]; }
    const e = st.estimate;
    if (e) {
      if (e.ellipse && e.ellipse.length) {
        ctx.strokeStyle = COLORS.estimate; ctx.lineWidth = 2; poly(e.ellipse, true); ctx.stroke();
        ctx.fillStyle = "rgba(37,99,235,0.12)"; ctx.fill();
        d.ellipse = e.ellipse.length;
      }
      drawRobot(e, COLORS.estimate, true);
      d.robot = [e.x, e.y];
      if (st.lookahead) {
        const c = view.toCanvas(e.x, e.y);
        ctx.beginPath(); ctx.arc(c[0], c[1], st.lookahead * scale(), 0, 2 * Math.PI);
        ctx.strokeStyle = COLORS.target; ctx.lineWidth = 1; ctx.setLineDash([3, 3]); ctx.stroke(); ctx.setLineDash([]);
      }
    }
    if (st.target) dots([st.target], COLORS.target, 5, false);
    if (drag) {
      poly([drag.start, drag.end]); ctx.strokeStyle = "#f97316"; ctx.lineWidth = 3; ctx.stroke();
      dots([drag.start], "#f97316", 6, false);
    }
    view.drawn = d;
  }

  // -- plots ------------------------------------------------------------------------------
  function plot(canvasId, size, series, opts) {
    const c = $(canvasId).getContext("2d"), W = size.w, H = size.h, L = 44, R = 8, T = 8, B = 20;
    c.clearRect(0, 0, W, H);
    c.fillStyle = "#fbfbfc"; c.fillRect(L, T, W - L - R, H - T - B);
    const t1 = opts.t1, t0 = t1 - opts.span;
    let ymax = opts.ymin || 0;
    series.forEach(function (s) { s.points.forEach(function (p) { if (p[0] >= t0 && p[1] > ymax) ymax = p[1]; }); });
    (opts.refs || []).forEach(function (r) { if (r * 1.3 > ymax) ymax = r * 1.3; });
    if (opts.ycap && ymax > opts.ycap) ymax = opts.ycap; // larger values are drawn at the top edge
    ymax = niceCeil(ymax * 1.1);
    const X = function (t) { return L + (t - t0) / (t1 - t0) * (W - L - R); };
    const Y = function (v) { return H - B - Math.min(v, ymax) / ymax * (H - T - B); };
    c.strokeStyle = "#e5e7eb"; c.fillStyle = "#6b7280"; c.font = "10px system-ui"; c.lineWidth = 1;
    for (let i = 0; i <= 4; i++) {
      const v = ymax * i / 4, y = Y(v);
      c.beginPath(); c.moveTo(L, y); c.lineTo(W - R, y); c.stroke();
      c.fillText(opts.fmt(v), 4, y + 3);
    }
    c.fillText(t0.toFixed(0) + " s", L, H - 5);
    c.textAlign = "right"; c.fillText(t1.toFixed(1) + " s", W - R, H - 5); c.textAlign = "start";
    (opts.refs || []).forEach(function (r, i) {
      c.strokeStyle = opts.refColors ? opts.refColors[i] : "#9ca3af"; c.setLineDash([4, 4]);
      c.beginPath(); c.moveTo(L, Y(r)); c.lineTo(W - R, Y(r)); c.stroke(); c.setLineDash([]);
    });
    series.forEach(function (s) {
      c.strokeStyle = s.color; c.lineWidth = 1.6; c.beginPath();
      let started = false;
      s.points.forEach(function (p) {
        if (p[0] < t0) return;
        if (!started) { c.moveTo(X(p[0]), Y(p[1])); started = true; } else c.lineTo(X(p[0]), Y(p[1]));
      });
      c.stroke();
    });
  }
  function niceCeil(v) {
    if (!(v > 0)) return 1;
    const e = Math.pow(10, Math.floor(Math.log10(v))), m = v / e;
    return (m <= 1 ? 1 : m <= 2 ? 2 : m <= 5 ? 5 : 10) * e;
  }

  function drawPlots(st, tNow) {
    // the plots span the last `history` seconds, or the run so far (at least 10 s) until then
    const history = view.history || 30;
    const t0 = Math.max(0, tNow - history), t1 = Math.max(tNow, t0 + 10), span = t1 - t0;
    const err = st.error || [];
    plot("error-plot", errSize, [{ points: err, color: COLORS.estimate }],
         { t1: t1, span: span, ymin: 0.01, fmt: function (v) { return (v * 100).toFixed(1) + " cm"; } });
    $("error-now").textContent = err.length ? (err[err.length - 1][1] * 100).toFixed(2) + " cm" : "–";
    const keys = Object.keys(st.nis || {}).sort();
    const series = [], refs = [], refColors = [];
    const legend = $("nis-legend");
    legend.innerHTML = "";
    keys.forEach(function (k, i) {
      const s = st.nis[k], color = NIS_COLORS[i % NIS_COLORS.length];
      series.push({ points: s.points, color: color });
      if (s.dof) { refs.push(s.dof); refColors.push(color + "88"); }
      if (s.band && s.band.length === 2) {  // the 95 % band of the period's mean (ekf_node diagnostics)
        refs.push(s.band[0], s.band[1]); refColors.push(color + "44", color + "44");
      }
      const lastV = s.points.length ? s.points[s.points.length - 1][1] : null;
      const last = lastV === null ? "–" : lastV.toFixed(2);
      const inBand = !s.band || lastV === null ? "" : (lastV >= s.band[0] && lastV <= s.band[1] ? " in" : " OUT");
      const el = document.createElement("span");
      el.innerHTML = '<i class="sw" style="background:' + color + '"></i>' + k + " " + last + " (dof " + (s.dof || "?") + ")"
        + (s.band ? " [" + s.band[0].toFixed(2) + ", " + s.band[1].toFixed(2) + "]" + inBand : "");
      legend.appendChild(el);
    });
    if (st.nees && st.nees.length) {  // NEES of (x, y) against the truth, χ²(2)
      series.push({ points: st.nees, color: "#000000" });
      refs.push(2); refColors.push("#00000088");
      const el = document.createElement("span");
      el.innerHTML = '<i class="sw" style="background:#000000"></i>NEES x,y ' + st.nees[st.nees.length - 1][1].toFixed(2) + " (dof 2)";
      legend.appendChild(el);
    }
    const cap = 8 * Math.max.apply(null, refs.concat([1]));
    plot("nis-plot", nisSize, series, { t1: t1, span: span, ymin: 1, ycap: cap, refs: refs, refColors: refColors,
                                       fmt: function (v) { return v.toFixed(1); } });
  }

  function drawStatus(st) {
    const s = st.status || { level: "STALE", message: view.connected ? "no ekf_node diagnostics yet" : "disconnected" };
    $("status").className = "status " + s.level;
    $("status-level").textContent = s.level;
    $("status-message").textContent = s.message;
    const body = $("statuses").tBodies[0];
    body.innerHTML = "";
    (st.statuses || []).forEach(function (x) {
      const tr = document.createElement("tr");
      tr.innerHTML = '<td class="level ' + x.level + '"></td><td></td><td></td>';
      tr.children[0].textContent = x.level; tr.children[1].textContent = x.name; tr.children[2].textContent = x.message;
      body.appendChild(tr);
    });
    const c = st.counters || {};
    $("counters").textContent = "page commands: set_pose " + (c.set_pose || 0) + ", reset " + (c.reset || 0) +
      ", bad messages " + (c.bad_messages || 0);
  }

  function render(st, tNow) {
    view.state = st;
    drawState(st);
    drawPlots(st, tNow);
    drawStatus(st);
    view.frames += 1;
  }

  // -- set_pose by click and drag, reset ---------------------------------------------------
  let arming = false, drag = null, socket = null;
  function send(obj) {
    view.sent.push(obj);
    if (socket && socket.readyState === 1) socket.send(JSON.stringify(obj));
  }
  function canvasPoint(ev) {
    const r = canvas.getBoundingClientRect();
    return view.toField(ev.clientX - r.left, ev.clientY - r.top);
  }
  function setArming(on) {
    arming = on;
    $("set-pose").classList.toggle("active", on);
    canvas.classList.toggle("arming", on);
    $("hint").textContent = on ? "click on the field; drag for the heading" : "";
  }
  $("set-pose").addEventListener("click", function () { setArming(!arming); });
  $("reset").addEventListener("click", function () { send({ type: "reset" }); });
  canvas.addEventListener("pointerdown", function (ev) {
    if (!arming || !view.field) return;
    const p = canvasPoint(ev);
    drag = { start: p, end: p };
    canvas.setPointerCapture && canvas.setPointerCapture(ev.pointerId);
  });
  canvas.addEventListener("pointermove", function (ev) {
    if (!drag) return;
    drag.end = canvasPoint(ev);
    if (view.state) drawState(view.state);
  });
  canvas.addEventListener("pointerup", function (ev) {
    if (!drag) return;
    const s = drag.start, e = canvasPoint(ev);
    const dx = e[0] - s[0], dy = e[1] - s[1];
    let yaw = Math.hypot(dx, dy) > 0.05 ? Math.atan2(dy, dx) : (view.state && view.state.estimate ? view.state.estimate.yaw : 0);
    drag = null;
    setArming(false);
    const h = view.field.size / 2;
    if (Math.abs(s[0]) <= h && Math.abs(s[1]) <= h) send({ type: "set_pose", x: s[0], y: s[1], yaw: yaw });
  });

  // -- live: WebSocket ---------------------------------------------------------------------
  function connect() {
    const proto = location.protocol === "https:" ? "wss://" : "ws://";
    const token = new URLSearchParams(location.search).get("token");  // served beyond localhost
    socket = new WebSocket(proto + location.host + "/ws" + (token ? "?token=" + encodeURIComponent(token) : ""));
    socket.onopen = function () { view.connected = true; };
    socket.onclose = function () {
      view.connected = false;
      if (view.state) drawStatus({ status: { level: "STALE", message: "disconnected: reconnecting…" } });
      setTimeout(connect, 1000);
    };
    socket.onmessage = function (ev) {
      const msg = JSON.parse(ev.data);
      if (msg.type === "field") { view.field = msg.field; view.history = msg.history; return; }
      if (msg.type === "state" && view.field) {
        const t = msg.estimate ? msg.estimate.t : (msg.truth ? msg.truth.t : 0);
        render(msg, t);
      }
    };
  }

  // -- replay: embedded frames and a slider -----------------------------------------------
  function replay(data) {
    view.field = data.field; view.history = data.history;
    $("replay").hidden = false;
    document.querySelector(".controls").hidden = true;
    $("counters").hidden = true;
    const slider = $("slider");
    slider.max = String(data.frames.length - 1);
    function show(i) {
      const f = data.frames[i], t = f.t;
      const cut = function (pts) { return pts.filter(function (p) { return p[0] <= t && p[0] >= t - data.history; }); };
      const nis = {};
      Object.keys(data.nis).forEach(function (k) { nis[k] = { dof: data.nis[k].dof, points: cut(data.nis[k].points) }; });
      const st = Object.assign({}, f, { path: data.path, error: cut(data.error), nis: nis, nees: cut(data.nees || []),
                                       status: f.status || data.status, statuses: f.statuses || data.statuses || [] });
      $("clock").textContent = t.toFixed(2) + " s";
      render(st, t);
    }
    slider.addEventListener("input", function () { show(Number(slider.value)); });
    let timer = null;
    $("play").addEventListener("click", function () {
      if (timer) { clearInterval(timer); timer = null; $("play").textContent = "Play"; return; }
      $("play").textContent = "Pause";
      timer = setInterval(function () {
        let i = Number(slider.value) + 1;
        if (i >= data.frames.length) i = 0;
        slider.value = String(i); show(i);
      }, 1000 / (data.rate || 10));
    });
    show(Number(slider.value));
    view.show = show;
  }

  if (window.FIELD_VIEW_EMBEDDED) replay(window.FIELD_VIEW_EMBEDDED); else connect();
})();
