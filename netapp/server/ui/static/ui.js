// The netapp's pages: no library, no CDN. /ui polls the robot list; /ui/robot/ID follows its Server-Sent Events.
"use strict";

// A netapp that needs its token is opened as /ui?token=TOKEN: every call below carries it on.
const TOKEN = new URLSearchParams(location.search).get("token");
const withToken = (url) => (TOKEN ? `${url}${url.includes("?") ? "&" : "?"}token=${encodeURIComponent(TOKEN)}` : url);

const PARTS = [["uplink_ms", "#1f77b4"], ["queue_ms", "#ff7f0e"], ["inference_ms", "#2ca02c"], ["downlink_ms", "#d62728"]];

// The colour of a class, as netapp.client.draw.class_colour computes it (OpenCV HSV: hue*2 degrees, s 220, v 255).
function classColour(classId) {
  const h = ((classId * 47) % 180) * 2, s = 220 / 255, v = 1;
  const f = (n) => { const k = (n + h / 60) % 6; return Math.round(255 * (v - v * s * Math.max(0, Math.min(k, 4 - k, 1)))); };
  return `rgb(${f(5)}, ${f(3)}, ${f(1)})`;
}

// How masks and poses are drawn, as the robot's drawing does (netapp/results.py); the events stream sends it first.
let STYLE = { mask_alpha: 0.45, keypoint_min_score: 0.5, coco_skeleton: [] };

const isNumber = (v) => typeof v === "number" && Number.isFinite(v);

// A compressed COCO RLE's runs (pycocotools' rleFrString), or null when the string is not one whose runs add up to
// height x width: the netapp checks what it sends, and the page checks again before it draws.
function rleRuns(counts, height, width) {
  if (typeof counts !== "string") return null;
  const runs = [];
  let p = 0;
  while (p < counts.length) {
    let x = 0, k = 0, more = true;
    while (more) {
      if (p >= counts.length || k > 6) return null;
      const c = counts.charCodeAt(p) - 48;
      if (c < 0 || c > 63) return null;
      x += (c & 0x1f) * 2 ** (5 * k);
      more = (c & 0x20) !== 0;
      p++; k++;
      if (!more && (c & 0x10)) x -= 2 ** (5 * k);
    }
    if (runs.length > 2) x += runs[runs.length - 2];
    if (x < 0) return null;
    runs.push(x);
  }
  return runs.reduce((a, b) => a + b, 0) === height * width ? runs : null;
}

// An RLE mask as a canvas of its own size, its pixels in `colour` (r, g, b), column-major as COCO counts them.
function rleCanvas(rle, colour) {
  const size = rle && rle.size;
  if (!Array.isArray(size) || size.length !== 2 || !size.every((v) => Number.isInteger(v) && v > 0)) return null;
  const [height, width] = size;
  const runs = rleRuns(rle.counts, height, width);
  if (!runs) return null;
  const canvas = document.createElement("canvas");
  canvas.width = width;
  canvas.height = height;
  const ctx = canvas.getContext("2d"), image = ctx.createImageData(width, height), data = image.data;
  let i = 0;
  runs.forEach((run, r) => {
    if (r % 2) {
      for (let j = i; j < i + run; j++) {
        const o = 4 * ((j % height) * width + Math.floor(j / height));
        data[o] = colour[0]; data[o + 1] = colour[1]; data[o + 2] = colour[2]; data[o + 3] = 255;
      }
    }
    i += run;
  });
  ctx.putImageData(image, 0, 0);
  return canvas;
}

// A detection's mask: polygons filled (even-odd) and outlined, or an RLE laid over the frame; translucent.
function drawMask(ctx, mask, colour, width, height) {
  if (!mask || typeof mask !== "object") return;
  ctx.save();
  if (Array.isArray(mask.polygons)) {
    ctx.beginPath();
    for (const p of mask.polygons) {
      if (!Array.isArray(p) || p.length < 6 || p.length % 2 || !p.every(isNumber)) continue;
      ctx.moveTo(p[0], p[1]);
      for (let j = 2; j < p.length; j += 2) ctx.lineTo(p[j], p[j + 1]);
      ctx.closePath();
    }
    ctx.globalAlpha = STYLE.mask_alpha;
    ctx.fillStyle = colour;
    ctx.fill("evenodd");
    ctx.globalAlpha = 1;
    ctx.lineWidth = 1;
    ctx.strokeStyle = colour;
    ctx.stroke();
  } else if (mask.rle) {
    const rgb = colour.match(/\d+/g).map(Number);
    const canvas = rleCanvas(mask.rle, rgb);
    if (canvas) {
      ctx.globalAlpha = STYLE.mask_alpha;
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(canvas, 0, 0, width, height);
    }
  }
  ctx.restore();
}

// Keypoints: the skeleton's limbs (COCO's for 17), then each sure keypoint as a white dot ringed in the colour.
function drawKeypoints(ctx, keypoints, colour) {
  if (!Array.isArray(keypoints)) return;
  const sure = keypoints.map((k) => (Array.isArray(k) && k.length === 3 && k.every(isNumber) &&
    k[2] >= STYLE.keypoint_min_score ? k : null));
  ctx.save();
  ctx.strokeStyle = colour;
  if (sure.length === 17) {
    for (const [a, b] of STYLE.coco_skeleton) {
      if (!sure[a] || !sure[b]) continue;
      ctx.beginPath();
      ctx.moveTo(sure[a][0], sure[a][1]);
      ctx.lineTo(sure[b][0], sure[b][1]);
      ctx.stroke();
    }
  }
  const radius = Math.max(3, ctx.lineWidth + 1);
  ctx.lineWidth = 1;
  for (const k of sure) {
    if (!k) continue;
    ctx.beginPath();
    ctx.arc(k[0], k[1], radius, 0, 2 * Math.PI);
    ctx.fillStyle = "#fff";
    ctx.fill();
    ctx.stroke();
  }
  ctx.restore();
}

// An oriented box [cx, cy, w, h, angle in radians] as its four sides.
function drawRbox(ctx, rbox, colour) {
  if (!Array.isArray(rbox) || rbox.length !== 5 || !rbox.every(isNumber)) return false;
  const [cx, cy, w, h, angle] = rbox;
  ctx.save();
  ctx.translate(cx, cy);
  ctx.rotate(angle);
  ctx.strokeStyle = colour;
  ctx.strokeRect(-w / 2, -h / 2, w, h);
  ctx.restore();
  return true;
}

function ms(value) { return value === null || value === undefined ? "–" : `${value.toFixed(1)} ms`; }

function kb(value) { return value === null || value === undefined ? "–" : value.toFixed(1); }

function cell(text) { const td = document.createElement("td"); td.textContent = text; return td; }

async function refreshIndex() {
  try {
    const response = await fetch(withToken("/ui/api/robots"), { cache: "no-store" });
    const { robots } = await response.json();
    const body = document.querySelector("#robots tbody");
    body.replaceChildren(...robots.map((r) => {
      const tr = document.createElement("tr");
      tr.dataset.id = r.id;
      const name = document.createElement("td");
      const link = document.createElement("a");
      link.href = withToken(`/ui/robot/${r.id}`);
      link.textContent = r.robot_id || r.id;
      name.append(link);
      tr.append(name, cell(r.transport), cell(r.results_per_s.toFixed(1)), cell(ms(r.latency_p50_ms)),
        cell(ms(r.latency_p95_ms)), cell(r.frame_size ?? "–"), cell(kb(r.kb_per_frame)), cell(r.received),
        cell(r.dropped), cell(r.rejected));
      return tr;
    }));
    document.getElementById("empty").hidden = robots.length > 0;
  } catch (error) {
    console.warn("robot list:", error);
  }
}

function drawChart(history) {
  const canvas = document.getElementById("chart"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!history.length) return;
  const total = (h) => PARTS.reduce((sum, [k]) => sum + (h[k] || 0), 0);
  const top = Math.max(1, ...history.map(total));
  const w = canvas.width / Math.max(history.length, 60), scale = (canvas.height - 14) / top;
  history.forEach((h, i) => {  // one stacked bar per result, uplink at the bottom
    let y = canvas.height;
    for (const [key, colour] of PARTS) {
      const height = (h[key] || 0) * scale;
      ctx.fillStyle = colour;
      ctx.fillRect(i * w, y - height, Math.max(1, w - 1), height);
      y -= height;
    }
  });
  ctx.fillStyle = "#444";
  ctx.fillText(`${top.toFixed(0)} ms`, 2, 10);
}

function drawFrame(event) {
  const canvas = document.getElementById("frame"), ctx = canvas.getContext("2d");
  const image = new Image();
  image.onload = () => {
    canvas.width = event.width;  // boxes come in the frame's pixels
    canvas.height = event.height;
    ctx.drawImage(image, 0, 0, event.width, event.height);
    const list = [];
    ctx.lineWidth = Math.max(2, Math.round(event.width / 320));
    ctx.font = `${Math.max(12, Math.round(event.width / 50))}px sans-serif`;
    const boxed = event.detections.filter((d) => d && Array.isArray(d.bbox) && d.bbox.length === 4);
    boxed.sort((a, b) => (a.score ?? 0) - (b.score ?? 0));  // the surest label drawn last, on top
    for (const d of boxed) drawMask(ctx, d.mask, classColour(d.class || 0), event.width, event.height);
    for (const d of boxed) {
      const [x1, y1, x2, y2] = d.bbox, colour = classColour(d.class || 0);
      const lineWidth = ctx.lineWidth;
      if (drawRbox(ctx, d.rbox, colour)) ctx.lineWidth = 1;  // the oriented box is the outline; its box thin
      ctx.strokeStyle = colour;
      ctx.strokeRect(x1, y1, x2 - x1, y2 - y1);
      ctx.lineWidth = lineWidth;
      drawKeypoints(ctx, d.keypoints, colour);
      const label = `${d.class_name ?? d.class} ${(d.score ?? 0).toFixed(2)}`;
      ctx.fillStyle = colour;
      ctx.fillRect(x1, Math.max(0, y1 - 16), ctx.measureText(label).width + 6, 16);
      ctx.fillStyle = "#000";
      ctx.fillText(label, x1 + 3, Math.max(12, y1 - 4));
      const li = document.createElement("li");
      li.textContent = label;
      li.dataset.bbox = JSON.stringify(d.bbox);
      li.dataset.class = d.class;
      if (d.mask) li.dataset.mask = d.mask.rle ? "rle" : "polygons";
      if (Array.isArray(d.keypoints)) li.dataset.keypoints = String(d.keypoints.length);
      list.push(li);
    }
    document.getElementById("detections").replaceChildren(...list);
    const classes = (event.classifications || []).filter((c) => c && typeof c === "object").slice(0, 5).map((c) => {
      const li = document.createElement("li");
      li.textContent = `${c.class_name ?? c.class} ${isNumber(c.score) ? c.score.toFixed(2) : ""}`;
      return li;
    });
    document.getElementById("classes").replaceChildren(...classes);
    document.getElementById("classes-title").hidden = classes.length === 0;
    if (classes.length) {  // a caption on the frame too, as the robot's drawing has
      const caption = classes.slice(0, 3).map((li) => li.textContent).join(", ");
      ctx.fillStyle = "rgba(0, 0, 0, 0.7)";
      ctx.fillRect(0, 0, ctx.measureText(caption).width + 8, parseInt(ctx.font, 10) + 8);
      ctx.fillStyle = "#fff";
      ctx.fillText(caption, 4, parseInt(ctx.font, 10) + 2);
    }
    const output = document.getElementById("output");  // a custom processor's own fields
    output.hidden = !event.output || event.output === "{}";
    output.textContent = output.hidden ? "" : event.output;
    document.body.dataset.frames = String(Number(document.body.dataset.frames) + 1);
    document.body.dataset.timestamp = String(event.timestamp);
  };
  image.src = event.frame;
}

async function startRobot() {
  const id = location.pathname.split("/").pop();
  const history = [];
  const title = document.getElementById("title"), stats = document.getElementById("stats");
  try {
    const response = await fetch(withToken(`/ui/api/robots/${id}`), { cache: "no-store" });
    if (!response.ok) { stats.textContent = (await response.json()).error; return; }
    const robot = await response.json();
    title.textContent = `Robot ${robot.robot_id || robot.id} (${robot.transport})`;
    history.push(...robot.history);
    drawChart(history);
  } catch (error) {
    stats.textContent = `cannot reach the netapp: ${error}`;
    return;
  }
  const source = new EventSource(withToken(`/ui/api/robots/${id}/events`));
  source.onmessage = (message) => {
    const event = JSON.parse(message.data);
    if (event.style) { STYLE = event.style; return; }
    if (event.gone) { stats.textContent = "the robot disconnected"; source.close(); return; }
    const s = event.stats;
    stats.textContent = `${s.results_per_s.toFixed(1)} results/s, latency p50 ${ms(s.latency_p50_ms)}, ` +
      `p95 ${ms(s.latency_p95_ms)}, dropped ${s.dropped}, rejected ${s.rejected}; ` +
      `frames ${s.frame_size ?? "–"} at ${kb(s.kb_per_frame)} KB`;
    if (event.latency) {
      history.push(event.latency);
      if (history.length > 120) history.shift();
      drawChart(history);
    }
    drawFrame(event);
  };
}

if (!location.pathname.startsWith("/ui/robot/")) {
  document.getElementById("index").hidden = false;
  document.querySelectorAll(".origin").forEach((e) => { e.textContent = location.origin; });
  refreshIndex();
  setInterval(refreshIndex, 1000);
} else {
  document.getElementById("robot").hidden = false;
  document.getElementById("back").href = withToken("/ui");
  startRobot();
}
