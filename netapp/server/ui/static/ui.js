// The netapp's pages: no library, no CDN. /ui polls the robot list; /ui/robot/ID follows its Server-Sent Events.
"use strict";

// A netapp that needs its token is opened as /ui?token=TOKEN: every call below carries it on.
const TOKEN = new URLSearchParams(location.search).get("token");
const withToken = (url) => (TOKEN ? `${url}${url.includes("?") ? "&" : "?"}token=${encodeURIComponent(TOKEN)}` : url);

const PARTS = [["uplink_ms", "#1f77b4"], ["queue_ms", "#ff7f0e"], ["inference_ms", "#2ca02c"], ["downlink_ms", "#d62728"]];

function ms(value) { return value === null || value === undefined ? "–" : `${value.toFixed(1)} ms`; }

function kb(value) { return value === null || value === undefined ? "–" : value.toFixed(1); }

function cell(text) { const td = document.createElement("td"); td.textContent = text; return td; }

// A model rollout under way or concluded (docs/rollouts.md): one line above the robots.
async function refreshRollout() {
  try {
    const r = await (await fetch("/rollout", { cache: "no-store" })).json();
    const line = document.getElementById("rollout");
    line.hidden = r.phase === "none";
    if (line.hidden) return;
    const agreement = r.agreement === null ? "–" : r.agreement.toFixed(3);
    line.textContent = `Rollout of ${r.model}: ${r.phase}, agreement ${agreement} over ${r.frames_compared} frames, ` +
      `p95 ${ms(r.p95_ms.current)} current, ${ms(r.p95_ms.candidate)} candidate` + (r.reason ? ` (${r.reason})` : "");
  } catch (error) {
    console.warn("rollout:", error);
  }
}

async function refreshIndex() {
  refreshRollout();
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
    const list = drawDetections(ctx, event.detections, event.width, event.height);
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
