// How the netapp's pages draw a result over its frame (/ui/robot/ID and /camera): no library, no CDN.
"use strict";

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

// An RLE mask (its runs read by `readMask`) as a canvas of its own size, its pixels in `colour` (r, g, b),
// column-major as COCO counts them.
function rleCanvas(rle, runs, colour) {
  const [height, width] = rle.size;
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

// A detection's mask (as `readDetections` checked it): polygons filled (even-odd) and outlined, or an RLE laid over
// the frame; translucent.
function drawMask(ctx, mask, colour, width, height) {
  ctx.save();
  if (mask.polygons) {
    ctx.beginPath();
    for (const p of mask.polygons) {
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
  } else {
    const rgb = colour.match(/\d+/g).map(Number);
    const canvas = rleCanvas(mask.rle, mask.runs, rgb);
    ctx.globalAlpha = STYLE.mask_alpha;
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(canvas, 0, 0, width, height);
  }
  ctx.restore();
}

// A pose (as `readDetections` checked it): the skeleton's limbs (COCO's for 17), then each sure keypoint as a white
// dot ringed in the colour.
function drawKeypoints(ctx, keypoints, colour) {
  const sure = keypoints.map((k) => (k[2] >= STYLE.keypoint_min_score ? k : null));
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

// An oriented box's four corners, as `Detections.rbox_corners` computes them.
function drawRbox(ctx, corners, colour) {
  ctx.save();
  ctx.strokeStyle = colour;
  ctx.beginPath();
  ctx.moveTo(corners[0][0], corners[0][1]);
  for (const [x, y] of corners.slice(1)) ctx.lineTo(x, y);
  ctx.closePath();
  ctx.stroke();
  ctx.restore();
}

const isNumbers = (v, n) => Array.isArray(v) && (n === undefined || v.length === n) && v.every(isNumber);

// What one detection may carry: netapp/results.py's MAX_* (tests/netapp/server/test_draw_js_reader.py pins them).
const BOUNDS = { polygons: 32, polygon_points: 1000, rle_chars: 65536, mask_side: 16384, keypoints: 133 };

// The one reader of a result's detections on the pages (netapp/detections.py's `Detections.from_wire`, leniently):
// each wire detection with a good box as {bbox, score, classId, label, colour, mask, keypoints, rbox}, its fields
// checked once (what is malformed is null, a custom processor's other output left out), the oriented box as its four
// corners. Every drawing path (the live page, the camera page) draws what this returns, and nothing else.
function readDetections(detections) {
  if (!Array.isArray(detections)) return [];
  const out = [];
  let keypointCount = null;  // one skeleton per result: keypoints of another length are left out
  for (const d of detections) {
    if (!d || typeof d !== "object" || !isNumbers(d.bbox, 4)) continue;
    const score = isNumber(d.score) ? d.score : null;
    const classId = Number.isInteger(d.class) && d.class >= 0 ? d.class : null;
    const name = typeof d.class_name === "string" ? d.class_name : (classId ?? "?");
    let keypoints = readKeypoints(d.keypoints);
    if (keypoints && (keypointCount ?? keypoints.length) !== keypoints.length) keypoints = null;
    if (keypoints) keypointCount = keypoints.length;
    out.push({
      bbox: d.bbox,
      score,
      classId,
      label: score === null ? String(name) : `${name} ${score.toFixed(2)}`,  // as Detections.label writes it
      colour: classColour(classId ?? 0),
      mask: readMask(d.mask),
      keypoints,
      rbox: isNumbers(d.rbox, 5) ? rboxCorners(d.rbox) : null,
    });
  }
  return out;
}

// A keypoints field: 1 to BOUNDS.keypoints [x, y, score] of finite numbers, else null.
function readKeypoints(keypoints) {
  const ok = Array.isArray(keypoints) && keypoints.length > 0 && keypoints.length <= BOUNDS.keypoints &&
    keypoints.every((k) => isNumbers(k, 3));
  return ok ? keypoints : null;
}

// A mask field within the bounds as {polygons} (those of 3 points or more: the rest have no area) or {rle, runs};
// null when it is neither.
function readMask(mask) {
  if (!mask || typeof mask !== "object") return null;
  if (Array.isArray(mask.polygons)) {
    const polygons = mask.polygons;
    const points = polygons.reduce((n, p) => n + (Array.isArray(p) ? p.length / 2 : 0), 0);
    if (polygons.length > BOUNDS.polygons || points > BOUNDS.polygon_points) return null;
    if (!polygons.every((p) => isNumbers(p) && p.length % 2 === 0)) return null;
    return { polygons: polygons.filter((p) => p.length >= 6) };
  }
  const rle = mask.rle, size = rle && rle.size;
  if (!Array.isArray(size) || size.length !== 2 || !size.every((v) => Number.isInteger(v) && v > 0 &&
    v <= BOUNDS.mask_side)) return null;
  if (typeof rle.counts !== "string" || rle.counts.length > BOUNDS.rle_chars) return null;
  const runs = rleRuns(rle.counts, size[0], size[1]);
  return runs ? { rle, runs } : null;
}

// [cx, cy, w, h, angle in radians] -> its four corners.
function rboxCorners([cx, cy, w, h, angle]) {
  const c = Math.cos(angle), s = Math.sin(angle);
  return [[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]]
    .map(([dx, dy]) => [cx + dx * c - dy * s, cy + dx * s + dy * c]);
}

// A result's detections drawn on `ctx` (a canvas of the frame's size: boxes come in the frame's pixels): masks, then
// boxes, oriented boxes, keypoints and labels; a list item for each (its data- attributes for tests). What is drawn
// is what `readDetections` read.
function drawDetections(ctx, detections, width, height) {
  const list = [];
  ctx.lineWidth = Math.max(2, Math.round(width / 320));
  ctx.font = `${Math.max(12, Math.round(width / 50))}px sans-serif`;
  const read = readDetections(detections);
  read.sort((a, b) => (a.score ?? 0) - (b.score ?? 0));  // the surest label drawn last, on top
  for (const d of read) if (d.mask) drawMask(ctx, d.mask, d.colour, width, height);
  for (const d of read) {
    const [x1, y1, x2, y2] = d.bbox;
    const lineWidth = ctx.lineWidth;
    if (d.rbox) {
      drawRbox(ctx, d.rbox, d.colour);
      ctx.lineWidth = 1;  // the oriented box is the outline; its box thin
    }
    ctx.strokeStyle = d.colour;
    ctx.strokeRect(x1, y1, x2 - x1, y2 - y1);
    ctx.lineWidth = lineWidth;
    if (d.keypoints) drawKeypoints(ctx, d.keypoints, d.colour);
    ctx.fillStyle = d.colour;
    ctx.fillRect(x1, Math.max(0, y1 - 16), ctx.measureText(d.label).width + 6, 16);
    ctx.fillStyle = "#000";
    ctx.fillText(d.label, x1 + 3, Math.max(12, y1 - 4));
    const li = document.createElement("li");
    li.textContent = d.label;
    li.dataset.bbox = JSON.stringify(d.bbox);
    li.dataset.class = d.classId;
    if (d.mask) li.dataset.mask = d.mask.rle ? "rle" : "polygons";
    if (d.keypoints) li.dataset.keypoints = String(d.keypoints.length);
    list.push(li);
  }
  return list;
}
