/* fleetmap live viewer: plain JavaScript, no build step.
 *
 * Draws the shared map on a canvas in one of three views (costmap, occupancy
 * probability, evidence age), the units with their planned paths, each unit in the look
 * of what it is doing (its posted activity: STATES), a legend and the map's metadata.
 * Units are listed and drawn in natural order of their ids (u2 before u10: byUnitId). The costmap is followed through
 * GET v1/costmap/updates?since=V patches; a full raw read happens only at start and when
 * the server answers {"full": true}. The occupancy and age views have no patch stream:
 * while one of them is shown it is read whole when the map's version has changed (at
 * most once per GRID_REFRESH_MS). Units come from GET v1/units, polled.
 * When the server stops answering (network errors, timeouts or non-2xx replies other than
 * 401/403) for GONE_AFTER_MS, a banner says so and the last map stays, marked stale;
 * the first answer again removes both.
 *
 * Grids: row-major, row 0 at the origin's y (the bottom row); the canvas shows +y up.
 * Auth: with tokens configured the API needs a reader token, taken from the URL fragment
 * (#token=...; removed from the address bar and kept in sessionStorage for the tab) or
 * asked for with a prompt on the first 401; it is sent as "Authorization: Bearer TOKEN".
 *
 * window.fleetmapViewer exposes the state for tests and the console (see the end).
 */
"use strict";

(() => {
  const POLL_MS = 500; // costmap updates poll period [ms]
  const UNITS_MS = 1000; // units poll period [ms]
  const RETRY_MS = 2000; // wait after a failed request [ms]
  const REQUEST_TIMEOUT_MS = 8000; // a request with no reply by then has failed [ms]
  const GONE_AFTER_MS = 3000; // failing this long: the server is not answering [ms]
  const GRID_REFRESH_MS = 1000; // occupancy / age views are read whole at most this often [ms]
  const STALE_UNIT_S = 10; // a unit state this much older than the map's stamp is faded [s]
  const LABEL_FONT_PX = 12; // unit labels' font size [CSS px]
  const LABEL_ROWS = 4; // rows above and below a marker a crowded label may move to
  const TOKEN_KEY = "fleetmap.token";
  const BACKGROUND = "#1b1d23";
  const COLOURS = { unit: [31, 111, 235], path: [10, 165, 201], frozen: [229, 72, 77] };
  /** The look of each unit activity (the server's UnitState.activity), in legend order. */
  const STATES = {
    moving: { words: "moving", colour: COLOURS.unit, shape: "disc" },
    waiting: { words: "waiting for traffic", colour: [245, 166, 35], shape: "yield" },
    frozen: { words: "frozen", colour: COLOURS.frozen, shape: "ringed" },
    broken_down: { words: "broken down", colour: [214, 51, 132], shape: "square" },
    dwelling: { words: "dwelling at a stop", colour: [46, 160, 67], shape: "diamond" },
    idle: { words: "idle (no task)", colour: [175, 182, 193], shape: "disc" },
  };
  /** A unit whose fleet posts no activity (and is not frozen). */
  const UNREPORTED = { words: "state not posted", colour: [100, 116, 139], shape: "disc" };
  const AGE_STOPS = [[253, 231, 37], [33, 145, 140], [68, 1, 84]]; // fresh .. old
  const COST_NAMES = { 0: "free", 253: "inscribed", 254: "lethal", 255: "unknown" };

  const $ = (selector) => document.querySelector(selector);
  const rgb = (c) => `rgb(${c[0]}, ${c[1]}, ${c[2]})`;
  const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
  const two = (n) => String(n).padStart(2, "0");
  const clock = (date) => `${two(date.getHours())}:${two(date.getMinutes())}:${two(date.getSeconds())}`;

  const collator = new Intl.Collator("en", { numeric: true });
  /** Natural order of unit ids: digit runs compare as numbers (u2 < u10), then by code unit. */
  function byUnitId(a, b) {
    return collator.compare(a.unit_id, b.unit_id) || (a.unit_id < b.unit_id ? -1 : a.unit_id > b.unit_id ? 1 : 0);
  }

  /** The activity key of a unit (a STATES key), or null when its fleet posts none. */
  function stateOf(unit) {
    if (unit.activity in STATES) return unit.activity;
    return unit.frozen ? "frozen" : null;
  }

  const lookOf = (unit) => STATES[stateOf(unit)] ?? UNREPORTED;

  // ------------------------------------------------------------------ token and API
  let token = tokenFromFragment() ?? stored(TOKEN_KEY);
  let tokenRefused = false;
  let tokenPrompt = null;

  function stored(key) {
    try {
      return sessionStorage.getItem(key);
    } catch {
      return null;
    }
  }

  function keep(key, value) {
    try {
      sessionStorage.setItem(key, value);
    } catch {
      /* storage disabled: the token lives as long as the page */
    }
  }

  /** The token in "#token=..." (then removed from the address bar), or null. */
  function tokenFromFragment() {
    const params = new URLSearchParams(location.hash.slice(1));
    const given = params.get("token");
    if (given === null) return null;
    params.delete("token");
    const rest = params.toString();
    history.replaceState(null, "", location.pathname + location.search + (rest ? `#${rest}` : ""));
    keep(TOKEN_KEY, given);
    return given;
  }

  /** Ask the user for a token once at a time; true when one was given. */
  function askToken() {
    if (tokenRefused) return Promise.resolve(false);
    tokenPrompt ??= Promise.resolve().then(() => {
      const given = window.prompt("This map server needs a reader token:", "");
      tokenPrompt = null;
      if (!given || !given.trim()) {
        tokenRefused = true;
        return false;
      }
      token = given.trim();
      keep(TOKEN_KEY, token);
      return true;
    });
    return tokenPrompt;
  }

  class ApiError extends Error {
    constructor(path, status, detail) {
      super(`${path}: HTTP ${status}: ${detail}`);
      this.status = status;
    }
  }

  /** GET path (relative to the page) with the bearer token; a 2xx Response or throws. */
  async function request(path) {
    for (let attempt = 0; ; attempt++) {
      const headers = token ? { Authorization: `Bearer ${token}` } : {};
      const signal = AbortSignal.timeout(REQUEST_TIMEOUT_MS);
      const response = await fetch(path, { headers, cache: "no-store", signal });
      if (response.ok) return response;
      if (response.status === 401 && attempt === 0 && (await askToken())) continue;
      let detail = response.statusText;
      try {
        detail = (await response.json()).detail ?? detail;
      } catch {
        /* not JSON: keep the status text */
      }
      throw new ApiError(path, response.status, detail);
    }
  }

  async function getJSON(path) {
    return (await request(path)).json();
  }

  /** A raw grid read: typed data plus the X-Map-* headers. */
  async function readRaw(path, ArrayType) {
    const response = await request(path);
    const header = (name) => response.headers.get(`X-Map-${name}`);
    const width = Number(header("Width"));
    const height = Number(header("Height"));
    const data = new ArrayType(await response.arrayBuffer());
    if (data.length !== width * height) {
      throw new Error(`${path}: ${data.length} values for a ${width} x ${height} grid`);
    }
    const stamp = Number(header("Stamp"));
    return {
      data,
      width,
      height,
      version: Number(header("Version")),
      stamp: Number.isFinite(stamp) ? stamp : null,
    };
  }

  // ------------------------------------------------------------------ map state
  const map = {
    meta: null,
    width: 0,
    height: 0,
    version: -1,
    stamp: null,
    costs: null, // Uint8Array, Nav2 costs
    grids: { occupancy: null, age: null }, // {data, version} read whole
  };
  const gridReadAt = { occupancy: -Infinity, age: -Infinity }; // performance.now() [ms]
  const stats = { fullReads: 0, updateReads: 0, patchesApplied: 0, gridReads: 0 };
  let units = [];
  let labels = []; // the unit labels as last placed: boxes [canvas px] (placeLabels)
  let markerReach = 0; // half the size [canvas px] labels keep clear of around a marker
  let view = "costmap";
  let palettes = null; // {cost: Uint8Array(768), occupancy: Uint8Array(768)}
  let ageLut = null; // Uint8Array(768): 256 steps from fresh to old
  let ageMax = 240; // [s] ages at or above this get the oldest colour

  const image = document.createElement("canvas"); // one pixel per cell, top row = max y
  const imageCtx = image.getContext("2d");
  let pixels = null;

  function setGeometry(width, height) {
    map.width = width;
    map.height = height;
    image.width = width;
    image.height = height;
    pixels = imageCtx.createImageData(width, height);
    map.grids = { occupancy: null, age: null };
    fit();
  }

  async function loadPalettes() {
    const response = await fetch("viewer/palette.json", { cache: "no-store" });
    const json = await response.json();
    palettes = { cost: new Uint8Array(json.cost.flat()), occupancy: new Uint8Array(json.occupancy.flat()) };
    ageLut = new Uint8Array(256 * 3);
    for (let i = 0; i < 256; i++) {
      const t = (i / 255) * (AGE_STOPS.length - 1);
      const k = Math.min(Math.floor(t), AGE_STOPS.length - 2);
      for (let c = 0; c < 3; c++) {
        ageLut[i * 3 + c] = Math.round(AGE_STOPS[k][c] + (AGE_STOPS[k + 1][c] - AGE_STOPS[k][c]) * (t - k));
      }
    }
  }

  /** Index into ageLut for an age [s]: a square-root scale from 0 to ageMax. */
  function ageStep(age) {
    return Math.round(255 * Math.sqrt(Math.min(Math.max(age, 0) / ageMax, 1)));
  }

  /** The RGB of cell index i in the current view. */
  function colourOf(i) {
    if (view === "costmap") {
      const k = map.costs[i] * 3;
      return palettes.cost.subarray(k, k + 3);
    }
    const grid = map.grids[view];
    if (view === "occupancy") {
      const k = (grid.data[i] & 255) * 3; // -1 (unknown) is 255
      return palettes.occupancy.subarray(k, k + 3);
    }
    const age = grid.data[i];
    if (Number.isNaN(age)) return palettes.cost.subarray(255 * 3, 256 * 3); // never observed
    const k = ageStep(age) * 3;
    return ageLut.subarray(k, k + 3);
  }

  function viewReady() {
    return view === "costmap" ? map.costs !== null : map.grids[view] !== null;
  }

  /** Paint cells x0..x0+w-1, y0..y0+h-1 of the current view into the cell image. */
  function paintRect(x0, y0, w, h) {
    if (!pixels || !viewReady()) return;
    const out = pixels.data;
    for (let row = y0; row < y0 + h; row++) {
      let dst = ((map.height - 1 - row) * map.width + x0) * 4;
      let src = row * map.width + x0;
      for (let col = 0; col < w; col++, src++, dst += 4) {
        const c = colourOf(src);
        out[dst] = c[0];
        out[dst + 1] = c[1];
        out[dst + 2] = c[2];
        out[dst + 3] = 255;
      }
    }
    imageCtx.putImageData(pixels, 0, 0, x0, map.height - y0 - h, w, h);
    requestDraw();
  }

  function paintAll() {
    paintRect(0, 0, map.width, map.height);
  }

  // ------------------------------------------------------------------ following the map
  async function readFullCostmap() {
    const grid = await readRaw("v1/costmap?format=raw", Uint8Array);
    stats.fullReads++;
    if (grid.width !== map.width || grid.height !== map.height) setGeometry(grid.width, grid.height);
    map.costs = grid.data;
    map.version = grid.version;
    map.stamp = grid.stamp;
    if (view === "costmap") paintAll();
  }

  /** Write one {x0, y0, width, height, data} patch; false if it does not fit the grid. */
  function applyPatch(patch) {
    const { x0, y0, width, height, data } = patch;
    if (x0 < 0 || y0 < 0 || x0 + width > map.width || y0 + height > map.height) return false;
    if (data.length !== width * height) return false;
    for (let r = 0; r < height; r++) {
      map.costs.set(data.slice(r * width, (r + 1) * width), (y0 + r) * map.width + x0);
    }
    stats.patchesApplied++;
    if (view === "costmap") paintRect(x0, y0, width, height);
    return true;
  }

  async function followCostmap() {
    const updates = await getJSON(`v1/costmap/updates?since=${map.version}`);
    stats.updateReads++;
    if (updates.full || !updates.patches.every(applyPatch)) {
      await readFullCostmap();
      return;
    }
    map.version = updates.version;
    if (updates.stamp !== null && updates.stamp !== undefined) map.stamp = updates.stamp;
  }

  /** Read the occupancy or age grid whole if it is shown and out of date. */
  async function refreshGridView(force = false) {
    if (view === "costmap") return;
    const name = view;
    const held = map.grids[name];
    if (held && held.version === map.version) return;
    if (!force && held && performance.now() - gridReadAt[name] < GRID_REFRESH_MS) return;
    gridReadAt[name] = performance.now();
    const grid =
      name === "occupancy"
        ? await readRaw("v1/map?format=raw", Int8Array)
        : await readRaw("v1/map/age?format=raw", Float32Array);
    stats.gridReads++;
    map.grids[name] = { data: grid.data, version: grid.version };
    if (view === name) paintAll();
  }

  async function pollMap() {
    try {
      if (!document.hidden) {
        await followCostmap();
        noteAnswer();
        await refreshGridView();
        showStatus();
      }
      setTimeout(pollMap, POLL_MS);
    } catch (err) {
      noteFailure(err);
      setTimeout(pollMap, RETRY_MS);
    }
  }

  async function pollUnits() {
    try {
      if (!document.hidden) {
        units = (await getJSON("v1/units")).units.sort(byUnitId);
        noteAnswer();
        renderUnits();
        requestDraw();
      }
      setTimeout(pollUnits, UNITS_MS);
    } catch (err) {
      noteFailure(err);
      setTimeout(pollUnits, RETRY_MS);
    }
  }

  // ------------------------------------------------------------------ is the server there?
  const link = { failingSince: null, answeredAt: null, timer: null, gone: false };

  /** A request failed: past GONE_AFTER_MS of failures (not 401/403) the server is gone. */
  function noteFailure(err) {
    showError(err);
    if (err instanceof ApiError && (err.status === 401 || err.status === 403)) return;
    if (link.failingSince !== null) return;
    link.failingSince = new Date();
    link.timer = setTimeout(markGone, GONE_AFTER_MS);
  }

  /** The server answered a request (2xx): it is there. */
  function noteAnswer() {
    link.answeredAt = new Date();
    if (link.failingSince === null) return;
    clearTimeout(link.timer);
    link.failingSince = null;
    if (!link.gone) return;
    link.gone = false;
    $("#banner").hidden = true;
    $("#stale-note").hidden = true;
    $("#stage").classList.remove("stale");
    requestDraw();
  }

  function markGone() {
    link.gone = true;
    const server = new URL(".", location.href).href;
    const banner = $("#banner");
    banner.textContent = `The map server at ${server} is not answering since ${clock(link.failingSince)}; retrying`;
    banner.hidden = false;
    const note = $("#stale-note");
    const last = link.answeredAt ? ` received at ${clock(link.answeredAt)}` : "";
    note.textContent = `stale: the last map${last} (version ${map.version}, stamp ${fmt(map.stamp, " s")})`;
    note.hidden = false;
    $("#stage").classList.add("stale");
    requestDraw();
  }

  // ------------------------------------------------------------------ drawing
  const canvas = $("#map");
  const ctx = canvas.getContext("2d");
  const camera = { scale: 1, ox: 0, oy: 0, fitted: true }; // canvas px per cell, image corner
  let drawPending = false;

  function fit() {
    if (!map.width) return;
    const scale = Math.min(canvas.width / map.width, canvas.height / map.height);
    camera.scale = scale > 0 ? scale : 1;
    camera.ox = (canvas.width - map.width * camera.scale) / 2;
    camera.oy = (canvas.height - map.height * camera.scale) / 2;
    camera.fitted = true;
    requestDraw();
  }

  function resize() {
    const dpr = window.devicePixelRatio || 1;
    canvas.width = Math.max(1, Math.round(canvas.clientWidth * dpr));
    canvas.height = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (camera.fitted) fit();
    draw();
  }

  function requestDraw() {
    if (drawPending) return;
    drawPending = true;
    requestAnimationFrame(() => {
      drawPending = false;
      draw();
    });
  }

  /** Canvas position [px] of the centre of cell (col, row). */
  function cellToCanvas(col, row) {
    const s = camera.scale;
    return [camera.ox + (col + 0.5) * s, camera.oy + (map.height - row - 0.5) * s];
  }

  /** Canvas position [px] of the world point (x, y) [m]. */
  function worldToCanvas(x, y) {
    const m = map.meta;
    const s = camera.scale;
    const cx = (x - m.origin.x) / m.resolution;
    const cy = (y - m.origin.y) / m.resolution;
    return [camera.ox + cx * s, camera.oy + (map.height - cy) * s];
  }

  /** The cell (col, row) under canvas position (px, py), or null off the map. */
  function canvasToCell(px, py) {
    const col = Math.floor((px - camera.ox) / camera.scale);
    const row = map.height - 1 - Math.floor((py - camera.oy) / camera.scale);
    if (col < 0 || row < 0 || col >= map.width || row >= map.height) return null;
    return [col, row];
  }

  function draw() {
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = BACKGROUND;
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    if (!map.width) return;
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(image, camera.ox, camera.oy, map.width * camera.scale, map.height * camera.scale);
    drawUnits();
  }

  function isStale(unit) {
    return map.stamp !== null && map.stamp - unit.stamp > STALE_UNIT_S;
  }

  /** Trace the outline of a marker of ``shape`` centred on (x, y), ``r`` [px] across. */
  function traceShape(c, shape, x, y, r) {
    c.beginPath();
    if (shape === "square") {
      const h = 0.85 * r;
      c.rect(x - h, y - h, 2 * h, 2 * h);
    } else if (shape === "diamond") {
      const h = 1.2 * r;
      c.moveTo(x, y - h);
      c.lineTo(x + h, y);
      c.lineTo(x, y + h);
      c.lineTo(x - h, y);
      c.closePath();
    } else if (shape === "yield") {
      const h = 1.25 * r; // a triangle pointing down, as a give-way sign
      c.moveTo(x - h, y - 0.6 * h);
      c.lineTo(x + h, y - 0.6 * h);
      c.lineTo(x, y + 1.1 * h);
      c.closePath();
    } else {
      c.arc(x, y, r, 0, 2 * Math.PI);
    }
  }

  /** One unit marker in ``look`` at (x, y) [px], radius ``r`` [px], heading ``yaw`` [rad]
   * (null: none); the map and the legend draw with it alike. */
  function drawMarker(c, look, x, y, r, yaw, dpr) {
    const colour = rgb(look.colour);
    traceShape(c, look.shape, x, y, r);
    c.fillStyle = colour;
    c.fill();
    c.lineWidth = 1.2 * dpr;
    c.strokeStyle = "rgba(0, 0, 0, 0.75)";
    c.stroke();
    if (look.shape === "square") {
      const h = 0.55 * r; // broken down: a cross on the square
      c.beginPath();
      c.moveTo(x - h, y - h);
      c.lineTo(x + h, y + h);
      c.moveTo(x + h, y - h);
      c.lineTo(x - h, y + h);
      c.strokeStyle = "#ffffff";
      c.lineWidth = 1.5 * dpr;
      c.stroke();
    }
    if (look.shape === "ringed") {
      c.beginPath();
      c.arc(x, y, r + 4 * dpr, 0, 2 * Math.PI);
      c.strokeStyle = colour;
      c.lineWidth = 2.5 * dpr;
      c.stroke();
    }
    if (yaw !== null) {
      c.beginPath();
      c.moveTo(x, y);
      c.lineTo(x + 1.7 * r * Math.cos(yaw), y - 1.7 * r * Math.sin(yaw));
      c.strokeStyle = colour;
      c.lineWidth = 2 * dpr;
      c.stroke();
    }
  }

  function drawUnits() {
    if (!map.meta) return;
    const dpr = window.devicePixelRatio || 1;
    const footprint = map.meta.inflation.inscribed_radius / map.meta.resolution; // [cells]
    const radius = Math.max(6 * dpr, footprint * camera.scale);
    ctx.font = `${LABEL_FONT_PX * dpr}px system-ui, "DejaVu Sans", sans-serif`;
    const marks = [];
    for (const unit of units) {
      ctx.globalAlpha = isStale(unit) ? 0.45 : 1;
      if (unit.path.length > 1) {
        ctx.beginPath();
        unit.path.forEach(([x, y], i) => {
          const [px, py] = worldToCanvas(x, y);
          if (i === 0) ctx.moveTo(px, py);
          else ctx.lineTo(px, py);
        });
        ctx.strokeStyle = rgb(COLOURS.path);
        ctx.lineWidth = 2 * dpr;
        ctx.setLineDash([6 * dpr, 4 * dpr]);
        ctx.stroke();
        ctx.setLineDash([]);
        const [gx, gy] = worldToCanvas(...unit.path[unit.path.length - 1]);
        ctx.fillStyle = rgb(COLOURS.path);
        ctx.fillRect(gx - 3 * dpr, gy - 3 * dpr, 6 * dpr, 6 * dpr);
      }
      const [x, y] = worldToCanvas(unit.pose.x, unit.pose.y);
      drawMarker(ctx, lookOf(unit), x, y, radius, unit.pose.yaw, dpr);
      const state = stateOf(unit);
      const text = state === null || state === "moving" ? unit.unit_id : `${unit.unit_id} (${STATES[state].words})`;
      marks.push({ unit, x, y, text, alpha: ctx.globalAlpha });
    }
    labels = placeLabels(marks, radius, dpr);
    for (const label of labels) drawLabel(label, dpr);
    ctx.globalAlpha = 1;
  }

  /** Where each unit's label goes [canvas px]: beside its marker, the first of the places
   * ``labelPlaces`` lists that stays on the canvas and overlaps no label placed before
   * and no other unit's marker; units close together (0.5 m) get places further up or
   * down, tied to their marker by a leader line. ``marks``: {unit, x, y, text, alpha}. */
  function placeLabels(marks, radius, dpr) {
    const reach = Math.max(1.4 * radius, radius + 7 * dpr); // a marker's half size, ring and all
    markerReach = reach;
    const markers = marks.map((m) => ({ unit: m.unit, left: m.x - reach, top: m.y - reach, right: m.x + reach, bottom: m.y + reach }));
    const height = (LABEL_FONT_PX + 4) * dpr;
    const placed = [];
    for (const mark of marks) {
      const width = ctx.measureText(mark.text).width + 4 * dpr;
      const places = labelPlaces(mark, width, height, radius, dpr);
      const fits = (box) =>
        box.left >= 0 && box.top >= 0 && box.right <= canvas.width && box.bottom <= canvas.height &&
        !placed.some((other) => overlaps(box, other)) &&
        !markers.some((m) => m.unit !== mark.unit && overlaps(box, m));
      const box = places.find(fits) || places[0];
      placed.push({ ...box, unit_id: mark.unit.unit_id, text: mark.text, x: mark.x, y: mark.y, radius, alpha: mark.alpha });
    }
    return placed;
  }

  /** The places a label of ``width`` x ``height`` [px] may take beside ``mark``, in order
   * of preference: above right, above left, below right, below left of the marker, then
   * rows further above and below, on either side (these with a leader line). */
  function labelPlaces(mark, width, height, radius, dpr) {
    const gap = 5 * dpr;
    const right = mark.x + radius + gap;
    const left = mark.x - radius - gap - width;
    const above = mark.y - radius - height;
    const below = mark.y + radius;
    const box = (l, t, leader) => ({ left: l, top: t, right: l + width, bottom: t + height, width, height, leader });
    const places = [box(right, above, false), box(left, above, false), box(right, below, false), box(left, below, false)];
    for (let row = 1; row <= LABEL_ROWS; row++) {
      const step = row * (height + 2 * dpr);
      for (const l of [right, left]) {
        places.push(box(l, above - step, true), box(l, below + step, true));
      }
    }
    return places;
  }

  function overlaps(a, b) {
    return a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;
  }

  /** One placed label: white text outlined dark, and its leader line to the marker. */
  function drawLabel(label, dpr) {
    ctx.globalAlpha = label.alpha;
    if (label.leader) {
      const lx = Math.min(Math.max(label.x, label.left), label.right); // nearest point of the box
      const ly = label.y < label.top ? label.top : label.bottom;
      const length = Math.hypot(lx - label.x, ly - label.y) || 1;
      ctx.beginPath(); // from the marker's edge
      ctx.moveTo(label.x + ((lx - label.x) * label.radius) / length, label.y + ((ly - label.y) * label.radius) / length);
      ctx.lineTo(lx, ly);
      ctx.strokeStyle = "rgba(0, 0, 0, 0.8)";
      ctx.lineWidth = 1.5 * dpr;
      ctx.stroke();
    }
    ctx.textAlign = "left";
    ctx.textBaseline = "middle";
    const tx = label.left + 2 * dpr;
    const ty = (label.top + label.bottom) / 2;
    ctx.lineWidth = 3 * dpr;
    ctx.strokeStyle = "rgba(0, 0, 0, 0.8)";
    ctx.strokeText(label.text, tx, ty);
    ctx.fillStyle = "#ffffff";
    ctx.fillText(label.text, tx, ty);
    ctx.textBaseline = "alphabetic";
  }

  // ------------------------------------------------------------------ panels
  function item(parent, tag, text, className) {
    const node = document.createElement(tag);
    node.textContent = text; // never HTML: unit ids and reasons come from the network
    if (className) node.className = className;
    parent.append(node);
    return node;
  }

  function swatch(parent, background, className = "") {
    const node = item(parent, "span", "", `swatch ${className}`);
    if (className === "line") node.style.borderTopColor = background;
    else node.style.background = background;
  }

  function legendRow(list, background, label, className) {
    const li = document.createElement("li");
    swatch(li, background, className);
    item(li, "span", label);
    list.append(li);
  }

  /** A small canvas with the marker of ``look``, as drawn on the map. */
  function markerIcon(look) {
    const dpr = window.devicePixelRatio || 1;
    const icon = document.createElement("canvas");
    icon.className = "marker";
    icon.width = icon.height = Math.round(22 * dpr);
    const half = icon.width / 2;
    drawMarker(icon.getContext("2d"), look, half, half, 6 * dpr, null, dpr);
    return icon;
  }

  /** The legend rows of the unit states: every activity, and "state not posted" while a
   * shown unit has none. */
  function renderStateLegend(list) {
    const keys = Object.keys(STATES);
    if (units.some((unit) => stateOf(unit) === null)) keys.push("unreported");
    for (const key of keys) {
      const look = STATES[key] ?? UNREPORTED;
      const li = document.createElement("li");
      li.className = "state";
      li.dataset.state = key;
      li.append(markerIcon(look));
      item(li, "span", look.words);
      list.append(li);
    }
  }

  function renderLegend() {
    const list = $("#legend");
    list.replaceChildren();
    const cost = (v) => rgb(palettes.cost.subarray(v * 3, v * 3 + 3));
    if (view === "costmap") {
      legendRow(list, cost(0), "free (0)");
      legendRow(list, `linear-gradient(90deg, ${cost(1)}, ${cost(126)}, ${cost(252)})`, "graded, inflated (1..252)");
      legendRow(list, cost(253), "inscribed (253)");
      legendRow(list, cost(254), "lethal (254)");
      legendRow(list, cost(255), "unknown (255)");
    } else if (view === "occupancy") {
      const occ = (v) => rgb(palettes.occupancy.subarray(v * 3, v * 3 + 3));
      legendRow(list, `linear-gradient(90deg, ${occ(0)}, ${occ(100)})`, "occupancy 0 .. 100 %");
      legendRow(list, occ(255), "unknown (-1)");
    } else {
      const stops = AGE_STOPS.map(rgb).join(", ");
      legendRow(list, `linear-gradient(90deg, ${stops})`, `evidence age 0 .. ${ageMax} s (square-root scale)`);
      legendRow(list, cost(255), "never observed");
    }
    renderStateLegend(list);
    legendRow(list, rgb(COLOURS.path), "planned path", "line");
  }

  const fmt = (value, unit = "") => (value === null || value === undefined ? "none" : `${+value.toFixed(4)}${unit}`);

  function renderMeta() {
    const m = map.meta;
    if (!m) return;
    const rows = [
      ["version", String(map.version)],
      ["stamp", fmt(map.stamp, " s")],
      ["size", `${m.width} x ${m.height} cells (${fmt(m.width * m.resolution, " m")} x ${fmt(m.height * m.resolution, " m")})`],
      ["resolution", fmt(m.resolution, " m/cell")],
      ["origin", `(${fmt(m.origin.x)}, ${fmt(m.origin.y)}) m`],
      ["frame", m.frame],
      ["policy", m.policy],
      ["thresholds", `occupied p > ${m.thresholds.occupied}, free p < ${m.thresholds.free}`],
      ["sensor", `p_hit ${m.sensor_model.p_hit}, p_miss ${m.sensor_model.p_miss}, clamp [${m.sensor_model.clamp_min}, ${m.sensor_model.clamp_max}]`],
      ["decay", m.policy === "decay"
        ? `half lives ${m.decay.half_life_occupied} s occupied, ${m.decay.half_life_free} s free; fade bound ${m.decay.fade_bound}`
        : "none under this policy"],
      ["inflation", `radius ${m.inflation.inflation_radius} m, inscribed ${m.inflation.inscribed_radius} m, k ${m.inflation.cost_scaling_factor} /m${m.inflation.inflate_unknown ? ", inflates unknown" : ""}`],
    ];
    const list = $("#meta");
    list.replaceChildren();
    for (const [name, value] of rows) {
      item(list, "dt", name);
      item(list, "dd", value, `meta-${name}`);
    }
  }

  let legendUnreported = false; // does the legend list "state not posted"?

  function renderUnits() {
    const list = $("#units");
    list.replaceChildren();
    if (units.length === 0) item(list, "li", "none published", "empty");
    for (const unit of units) {
      const state = stateOf(unit);
      const li = document.createElement("li");
      li.dataset.unit = unit.unit_id;
      li.className = [state ?? "unreported", isStale(unit) ? "stale" : ""].join(" ").trim();
      const head = item(li, "div", "", "head");
      head.append(markerIcon(lookOf(unit)));
      item(head, "span", unit.unit_id, "id");
      item(head, "span", lookOf(unit).words, "state");
      const where = `(${unit.pose.x.toFixed(2)}, ${unit.pose.y.toFixed(2)}) m at ${unit.stamp.toFixed(1)} s`;
      item(li, "div", where, "detail");
      if (unit.reason) item(li, "div", unit.reason, "reason");
      list.append(li);
    }
    const unreported = units.some((unit) => stateOf(unit) === null);
    if (unreported !== legendUnreported && palettes) {
      legendUnreported = unreported;
      renderLegend();
    }
  }

  function showStatus() {
    const status = $("#status");
    status.classList.remove("error");
    status.textContent = `live · version ${map.version} · stamp ${fmt(map.stamp, " s")}`;
    renderMeta();
  }

  function showError(err) {
    const status = $("#status");
    status.classList.add("error");
    if (err instanceof ApiError && err.status === 401) {
      status.textContent = "needs a reader token: use Token… or open the page as /#token=TOKEN";
    } else if (err instanceof ApiError) {
      status.textContent = err.message;
    } else {
      status.textContent = `cannot reach the map server (${err.message}); retrying`;
    }
    console.warn("fleetmap viewer:", err.message);
  }

  /** The value under cell (col, row) in the current view, for the hover line and tests. */
  function valueAt(col, row) {
    const i = row * map.width + col;
    if (view === "costmap") return map.costs ? map.costs[i] : null;
    const grid = map.grids[view];
    if (!grid) return null;
    const value = grid.data[i];
    return Number.isNaN(value) ? null : value;
  }

  function describe(col, row) {
    const value = valueAt(col, row);
    const m = map.meta;
    const x = m.origin.x + (col + 0.5) * m.resolution;
    const y = m.origin.y + (row + 0.5) * m.resolution;
    let text;
    if (view === "costmap") text = `cost ${value}${COST_NAMES[value] ? ` (${COST_NAMES[value]})` : ""}`;
    else if (view === "occupancy") text = value === null || value < 0 ? "unknown" : `p ${value} %`;
    else text = value === null ? "never observed" : `age ${value.toFixed(1)} s`;
    return `cell (${col}, ${row}) · (${x.toFixed(2)}, ${y.toFixed(2)}) m · ${text}`;
  }

  // ------------------------------------------------------------------ interaction
  async function setView(name) {
    if (!["costmap", "occupancy", "age"].includes(name)) throw new Error(`no view named ${name}`);
    view = name;
    const radio = document.querySelector(`input[name=view][value=${name}]`);
    if (radio) radio.checked = true;
    renderLegend();
    try {
      await refreshGridView(true);
    } catch (err) {
      showError(err);
    }
    paintAll();
  }

  function setUpInteraction() {
    for (const radio of document.querySelectorAll("input[name=view]")) {
      radio.addEventListener("change", () => setView(radio.value));
    }
    $("#fit").addEventListener("click", fit);
    $("#token").addEventListener("click", () => {
      tokenRefused = false;
      askToken();
    });
    canvas.addEventListener("dblclick", fit);
    canvas.addEventListener(
      "wheel",
      (event) => {
        event.preventDefault();
        const dpr = window.devicePixelRatio || 1;
        const [mx, my] = [event.offsetX * dpr, event.offsetY * dpr];
        const factor = Math.exp(-event.deltaY * 0.0015);
        const scale = Math.min(Math.max(camera.scale * factor, 0.05), 64);
        camera.ox = mx - ((mx - camera.ox) * scale) / camera.scale;
        camera.oy = my - ((my - camera.oy) * scale) / camera.scale;
        camera.scale = scale;
        camera.fitted = false;
        requestDraw();
      },
      { passive: false },
    );
    let drag = null;
    canvas.addEventListener("mousedown", (event) => {
      drag = { x: event.clientX, y: event.clientY };
      canvas.classList.add("dragging");
    });
    window.addEventListener("mouseup", () => {
      drag = null;
      canvas.classList.remove("dragging");
    });
    canvas.addEventListener("mousemove", (event) => {
      const dpr = window.devicePixelRatio || 1;
      if (drag) {
        camera.ox += (event.clientX - drag.x) * dpr;
        camera.oy += (event.clientY - drag.y) * dpr;
        camera.fitted = false;
        drag = { x: event.clientX, y: event.clientY };
        requestDraw();
      }
      const cell = map.width ? canvasToCell(event.offsetX * dpr, event.offsetY * dpr) : null;
      $("#hover").textContent = cell ? describe(...cell) : "";
    });
    canvas.addEventListener("mouseleave", () => {
      $("#hover").textContent = "";
    });
    new ResizeObserver(resize).observe(canvas);
  }

  // ------------------------------------------------------------------ start
  let markReady;
  const ready = new Promise((resolve) => {
    markReady = resolve;
  });

  async function start() {
    setUpInteraction();
    resize();
    for (;;) {
      try {
        await loadPalettes();
        map.meta = await getJSON("v1/map/meta");
        const decay = map.meta.decay;
        ageMax = Math.round(2 * Math.max(decay.half_life_occupied, decay.half_life_free));
        setGeometry(map.meta.width, map.meta.height);
        await readFullCostmap();
        noteAnswer();
        break;
      } catch (err) {
        noteFailure(err);
        await sleep(RETRY_MS);
      }
    }
    renderLegend();
    showStatus();
    markReady();
    pollMap();
    pollUnits();
  }

  window.fleetmapViewer = {
    ready, // resolves once the metadata and the first costmap are in
    stats, // fullReads, updateReads, patchesApplied, gridReads
    colours: COLOURS,
    states: STATES, // activity -> {words, colour, shape}
    byUnitId, // the one comparator of unit ids (natural order)
    get serverGone() {
      return link.gone;
    },
    get version() {
      return map.version;
    },
    get view() {
      return view;
    },
    get units() {
      return units;
    },
    /** The unit labels as drawn: {unit_id, text, left, top, right, bottom, leader, x, y}
     * [canvas px] (x, y: the unit's marker), after a synchronous redraw. */
    get labels() {
      draw();
      return labels.map(({ unit_id, text, left, top, right, bottom, leader, x, y }) => ({ unit_id, text, left, top, right, bottom, leader, x, y }));
    },
    get markerReach() {
      return markerReach;
    },
    setView, // "costmap" | "occupancy" | "age"; resolves once the view is painted
    valueAt,
    cellToCanvas,
    /** [r, g, b, a] drawn at the centre of cell (col, row), after a synchronous redraw. */
    pixelAt(col, row) {
      draw();
      const [x, y] = cellToCanvas(col, row);
      return Array.from(ctx.getImageData(Math.floor(x), Math.floor(y), 1, 1).data);
    },
  };

  start();
})();
