// /camera: getUserMedia's video to the netapp over WebRTC (POST /webrtc/offer, non-trickle ICE), the results from the
// data channel drawn over the picture with the live page's drawing (draw.js).
"use strict";

// A netapp that needs its token is opened as /camera?token=TOKEN; the offer carries it as a bearer token.
const TOKEN = new URLSearchParams(location.search).get("token");
const ICE_WAIT_MS = 5000;  // longest wait for this browser's candidates before the offer goes without the rest

const status = (text, state) => {
  document.getElementById("status").textContent = text;
  if (state) document.body.dataset.state = state;
};

function waitForCandidates(pc) {
  if (pc.iceGatheringState === "complete") return Promise.resolve();
  return new Promise((resolve) => {
    const done = () => { if (pc.iceGatheringState === "complete") resolve(); };
    pc.addEventListener("icegatheringstatechange", done);
    setTimeout(resolve, ICE_WAIT_MS);
  });
}

function draw(video, message, frameSize) {
  const canvas = document.getElementById("frame"), ctx = canvas.getContext("2d");
  // Boxes come in the pixels of the picture the netapp decoded, which the browser may have scaled down to send; the
  // canvas takes that size and the page stretches it over the video.
  const [width, height] = Array.isArray(frameSize) ? frameSize : [video.videoWidth, video.videoHeight];
  if (!width || !height) return;
  canvas.width = width;  // clears it too
  canvas.height = height;
  const list = drawDetections(ctx, Array.isArray(message.detections) ? message.detections : [], width, height);
  document.getElementById("detections").replaceChildren(...list);
  document.body.dataset.results = String(Number(document.body.dataset.results) + 1);
  document.body.dataset.boxes = String(list.length);
}

async function start() {
  document.getElementById("start").disabled = true;
  let stream;
  try {
    stream = await navigator.mediaDevices.getUserMedia({ video: { width: 1280, height: 720 }, audio: false });
  } catch (error) {
    status(`no camera: ${error.message} (a phone needs https://, see docs/cameras.md#webrtc)`, "failed");
    return;
  }
  const video = document.getElementById("video");
  video.srcObject = stream;
  const pc = new RTCPeerConnection({ iceServers: [] });  // none: the netapp is reached directly (or via its TURN)
  const channel = pc.createDataChannel("results");
  channel.onmessage = (message) => {
    let parsed;
    try { parsed = JSON.parse(message.data); } catch { return; }
    if (parsed.event === "results" && parsed.data) draw(video, parsed.data, parsed.frame_size);
    else if (parsed.event === "error" && parsed.data) status(`netapp: ${parsed.data.error}`);
  };
  for (const track of stream.getVideoTracks()) {
    const sender = pc.addTrack(track, stream);
    const parameters = sender.getParameters();
    parameters.degradationPreference = "maintain-resolution";  // fewer frames rather than smaller ones
    sender.setParameters(parameters).catch(() => {});
  }
  pc.onconnectionstatechange = () => status(`connection ${pc.connectionState}`, pc.connectionState);
  await pc.setLocalDescription(await pc.createOffer());
  await waitForCandidates(pc);
  const headers = { "Content-Type": "application/json" };
  if (TOKEN) headers.Authorization = `Bearer ${TOKEN}`;
  const response = await fetch("/webrtc/offer", {
    method: "POST", headers, body: JSON.stringify({ type: "offer", sdp: pc.localDescription.sdp, robot_id: "browser" }),
  });
  const answer = await response.json();
  if (!response.ok) { status(`refused: ${answer.error || response.status}`, "refused"); return; }
  await pc.setRemoteDescription({ type: "answer", sdp: answer.sdp });
  status("connecting");
}

document.getElementById("start").addEventListener("click", start);
if (new URLSearchParams(location.search).has("start")) start();
