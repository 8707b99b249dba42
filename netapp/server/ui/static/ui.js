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
    for (const d of boxed) {
      const [x1, y1, x2, y2] = d.bbox, colour = classColour(d.class || 0);
      ctx.strokeStyle = colour;
      ctx.strokeRect(x1, y1, x2 - x1, y2 - y1);
      const label = `${d.class_name ?? d.class} ${(d.score ?? 0).toFixed(2)}`;
      ctx.fillStyle = colour;
      ctx.fillRect(x1, Math.max(0, y1 - 16), ctx.measureText(label).width + 6, 16);
      ctx.fillStyle = "#000";
      ctx.fillText(label, x1 + 3, Math.max(12, y1 - 4));
      const li = document.createElement("li");
      li.textContent = label;
      li.dataset.bbox = JSON.stringify(d.bbox);
      li.dataset.class = d.class;
      list.push(li);
    }
    document.getElementById("detections").replaceChildren(...list);
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
