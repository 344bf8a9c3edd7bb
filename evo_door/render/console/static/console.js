/* evo-door operator's console: the page side of its messages with the console's server
 * (evo_door/render/console/server.py).
 *
 * Plain JavaScript, no build step, nothing loaded from outside 127.0.0.1.
 * The server (evo_door/render/console/server.py) serves this file, GET /api/declaration,
 * GET /api/curve and the WebSocket /ws; every number in a message is SI (rad, rad/s, N),
 * the page shows angles in degrees, labelled, and every number with its unit.
 * The rendered model comes with the declaration (its "model": name, the handle's unit
 * and range, door): the haptic model's page shows the door, its latch and JND sessions;
 * another model's (a mechanism) shows its handle on its stroke, in its unit (a linear
 * handle's position in m), and the parameters a page may change of it.
 *
 * Conventions (docs/conventions.md): theta 0 = fully open (door horizontal), pi/2 = closed
 * (vertical); force + toward closing; opening means dtheta < 0.
 */
"use strict";

(function () {
  const DEG = 180 / Math.PI;
  const CLOSED = Math.PI / 2;
  const WINDOW_S = 10; // seconds of history in the traces and the strip chart
  const RECONNECT_MS = 1000;
  const ON_TIME_MIN = 0.999; // the loop's target: >= 99.9 % of cycles on time
  const STALE_TICK_S = 1.5; // no tick for this long while connected: warn
  const SLIDE_FULL_DEG_S = 90; // sliding sound at full loudness from this speed
  const LATCH_HYST = 0.2 / DEG; // rad, see Latch below
  const TARGET_TTL_MS = 1000; // how long a sent, unconfirmed value is the base of the next key
  const KEY_REPEAT_MS = 100; // a held key steps at most this often
  // unit conversions for display: {SI unit: {display unit: factor}}
  const CONVERT = { rad: { deg: DEG } };

  // ---------------------------------------------------------------- state
  const S = {
    decl: [], // rows of /api/declaration, the parameters a page may change, declaration order
    // the rendered model (/api/declaration): the haptic model's door until it says otherwise
    model: { name: "haptic", title: "", unit: "rad", range: [0, CLOSED], door: true, jnd: true },
    byName: {},
    keyMap: {}, // key -> {name, dir}
    display: { rad: "deg" },
    inForce: {}, // name -> SI value in force (from hello / params)
    start: {}, // the starting set (Reset goes back to it)
    target: {}, // name -> {value, at}: sent and not yet confirmed
    dragging: {}, // name -> true while the pointer holds its slider
    ab: { A: null, B: null, active: null, blind: false },
    jnd: null, // the JND session (the server's latest jnd message), or null
    participant: "",
    rows: { t: [], theta: [], dtheta: [], force: [] },
    state: null, // latest tick's state
    health: null,
    tickAt: 0, // performance.now() of the latest tick
    connected: false,
    curve: null,
    dirty: true,
    lastKeyAt: {},
    latchCount: { lock: 0, unlock: 0 }, // latch clicks heard (or due, when muted)
  };
  // for debugging and tests (S: the page's state; send: a raw message to the server)
  window.evoConsole = S;

  const $ = (id) => document.getElementById(id);
  const query = new URLSearchParams(location.search);
  const TOKEN = query.get("token");

  function withToken(path) {
    return TOKEN ? path + (path.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(TOKEN) : path;
  }

  // ---------------------------------------------------------------- formatting
  function fmt(v, digits) {
    if (v === null || v === undefined || !isFinite(v)) return "-";
    if (Math.abs(v) < 1e-12) return "0";
    const d = digits || 4;
    let s = String(Number(v.toPrecision(d)));
    if (s.includes("e")) s = v.toPrecision(3);
    return s;
  }

  function displayUnit(unit) {
    const to = S.display[unit];
    return to && CONVERT[unit] && CONVERT[unit][to] ? to : unit;
  }

  function toDisplay(unit, v) {
    const to = S.display[unit];
    const f = to && CONVERT[unit] && CONVERT[unit][to];
    return f ? v * f : v;
  }

  // toFixed without "-0.0"
  function fixed(v, d) {
    const s = v.toFixed(d);
    return /^-0\.?0*$/.test(s) ? s.slice(1) : s;
  }

  function withUnit(unit, v) {
    const u = displayUnit(unit);
    const n = fmt(toDisplay(unit, v));
    return u === "1" || u === "" ? n : n + " " + u;
  }

  // 12 significant digits, as evo_door.render.keys.key_change: no 0.30000000000000004
  function round12(v) {
    return Number(v.toPrecision(12));
  }

  function clamp(v, lo, hi) {
    return Math.min(Math.max(v, lo), hi);
  }

  // the handle's coordinate for people: an angle (rad) in degrees, a position in its unit
  function handleScale() {
    return S.model.unit === "rad" ? DEG : 1;
  }

  function handleUnit() {
    return S.model.unit === "rad" ? "deg" : S.model.unit;
  }

  function handleWord() {
    return S.model.unit === "rad" ? "angle" : "position";
  }

  // digits after the point of the handle's coordinate shown (0.1 deg; 1 mm on a 0.45 m stroke)
  function handleDigits() {
    const span = (S.model.range[1] - S.model.range[0]) * handleScale();
    return Math.max(1, Math.min(4, 3 - Math.floor(Math.log10(span))));
  }

  function setModel(m) {
    const range = Array.isArray(m.range) && m.range.length === 2 ? m.range.map(Number) : [0, CLOSED];
    S.model = {
      name: String(m.name || ""),
      title: String(m.title || ""),
      unit: String(m.unit || "rad"),
      range: range[1] > range[0] ? range : [0, CLOSED],
      door: m.door !== false,
      jnd: m.jnd !== false,
    };
    $("jnd-panel").hidden = !S.model.jnd;
    $("zoom-latch").hidden = !S.model.door;
    if (!S.model.door) {
      S.zoomLatch = false;
      $("door-title").textContent = "Mechanism " + S.model.name;
      $("door-title").title = S.model.title;
      $("curve-title").textContent = "Force against " + handleWord();
      $("door").setAttribute("aria-label", "The handle of " + S.model.name + " on its stroke, in " +
        handleUnit());
      $("force-angle").setAttribute("aria-label", "User force in newtons against the handle's " +
        handleWord() + " in " + handleUnit() + ", live trace over the model's opening and closing curves");
    }
    latch.configure(S.inForce);
    invalidate();
  }

  // ---------------------------------------------------------------- message area
  let messageTimer = null;
  function setMessage(text, kind) {
    const el = $("message");
    el.textContent = text;
    el.title = text;
    el.className = text ? kind || "info" : "";
    clearTimeout(messageTimer);
    if (text) {
      messageTimer = setTimeout(() => setMessage("", ""), kind === "error" ? 20000 : 6000);
    }
  }

  // ---------------------------------------------------------------- WebSocket
  let ws = null;

  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    let sock;
    try {
      sock = new WebSocket(proto + "//" + location.host + withToken("/ws"));
    } catch (err) {
      setTimeout(connect, RECONNECT_MS);
      return;
    }
    ws = sock;
    sock.onopen = () => setConnected(true);
    sock.onmessage = (ev) => {
      let msg;
      try {
        msg = JSON.parse(ev.data);
      } catch (err) {
        return;
      }
      handle(msg);
    };
    sock.onclose = () => {
      if (ws === sock) ws = null;
      setConnected(false);
      setTimeout(connect, RECONNECT_MS);
    };
    sock.onerror = () => {
      /* onclose follows and reconnects */
    };
  }

  function send(msg) {
    if (!ws || ws.readyState !== WebSocket.OPEN) {
      setMessage("Not connected to the console server: nothing was sent", "error");
      return false;
    }
    ws.send(JSON.stringify(msg));
    return true;
  }

  function setConnected(on) {
    S.connected = on;
    if (on) {
      // a new connection may reach another renderer: nothing of the last one is shown
      // as current (its "running", its tick time) until the hello says what runs now
      S.health = null;
      S.state = null;
      S.tickAt = 0;
    }
    const el = $("connection");
    el.textContent = on ? "connected" : "disconnected";
    el.className = on ? "good" : "bad";
    if (on && !S.decl.length) loadDeclaration();
    updateHealth();
  }

  function handle(msg) {
    switch (msg.type) {
      case "hello":
        S.start = msg.start || {};
        if (typeof msg.participant === "string" && document.activeElement !== $("participant")) {
          $("participant").value = msg.participant;
        }
        S.participant = msg.participant || "";
        if (msg.ab) setAB(msg.ab);
        if (msg.jnd) setJnd(msg.jnd);
        S.target = {};
        applyParams(msg.params || {}, "hello");
        if (Array.isArray(msg.rows)) loadHistory(msg.rows);
        // the loop's health as the page opened: shown at once, not from the first tick
        if (msg.health) S.health = msg.health;
        if (msg.state) S.state = msg.state;
        S.tickAt = performance.now();
        updateHealth();
        break;
      case "tick":
        onTick(msg);
        break;
      case "params":
        applyParams(msg.params || {}, msg.source);
        break;
      case "refused":
        onRefused(msg);
        break;
      case "saved":
        $("saved-path").textContent = "Saved: " + msg.path;
        $("saved-path").title = msg.path;
        setMessage("Saved the set in force to " + msg.path, "info");
        break;
      case "ab":
        setAB(msg);
        break;
      case "jnd":
        setJnd(msg);
        break;
      case "jnd_phase":
        if (S.jnd) {
          S.jnd.phase = msg.phase;
          S.jnd.trial = msg.trial;
          renderJndPhase();
        }
        break;
      case "participant":
        S.participant = msg.id || "";
        if (document.activeElement !== $("participant")) $("participant").value = S.participant;
        break;
      case "chosen":
        setMessage(
          "Recorded as the final choice" + (msg.participant ? " of participant " + msg.participant : "") +
            ": the set in force",
          "info"
        );
        break;
      case "error":
        setMessage(msg.error || "error", "error");
        break;
      default:
        break;
    }
  }

  // ---------------------------------------------------------------- declaration and sliders
  let declTimer = null;
  let declLoading = false;
  function loadDeclaration() {
    if (declLoading) return;
    declLoading = true;
    clearTimeout(declTimer);
    fetch(withToken("/api/declaration"), { cache: "no-store" })
      .then((r) => {
        if (!r.ok) throw new Error("GET /api/declaration: HTTP " + r.status);
        return r.json();
      })
      .then((d) => {
        S.display = d.display || S.display;
        if (d.model) setModel(d.model);
        buildSliders(d.params || []);
      })
      .catch((err) => {
        setMessage(String(err.message || err) + " (retrying)", "error");
        declTimer = setTimeout(loadDeclaration, 2000);
      })
      .finally(() => {
        declLoading = false;
      });
  }

  // numbered families (friction_scale_1 .. friction_scale_8): two per row, short labels
  function families(rows) {
    const count = {};
    for (const p of rows) {
      const m = /^(.*)_(\d+)$/.exec(p.name);
      if (m) count[m[1]] = (count[m[1]] || 0) + 1;
    }
    return count;
  }

  function shortLabel(p) {
    const m = /\[\s*([-\d.]+)\s*,\s*([-\d.]+)\s*\]\s*deg/.exec(p.meaning || "");
    if (m) return Math.round(Number(m[1])) + "-" + Math.round(Number(m[2])) + " deg";
    return "#" + /_(\d+)$/.exec(p.name)[1];
  }

  function buildSliders(rows) {
    S.decl = rows;
    S.byName = {};
    S.keyMap = {};
    const box = $("sliders");
    box.textContent = "";
    const fam = families(rows);
    let group = null;
    let groupName = null;
    for (const p of rows) {
      if (Array.isArray(p.range) && p.range.length === 2) {
        // a mechanism's slider range, inside its declared bounds (sensations.py): the
        // page's bounds from here on; the declared ones in the row's title
        p.declared = [p.lower, p.upper];
        p.lower = Number(p.range[0]);
        p.upper = Number(p.range[1]);
      }
      S.byName[p.name] = p;
      const [down, up] = p.keys || [];
      if (down) S.keyMap[down] = { name: p.name, dir: -1 };
      if (up) S.keyMap[up] = { name: p.name, dir: +1 };
      const m = /^(.*)_(\d+)$/.exec(p.name);
      const inFamily = m && fam[m[1]] >= 2;
      if (inFamily) {
        if (groupName !== m[1]) {
          groupName = m[1];
          group = document.createElement("div");
          group.className = "family";
          group.setAttribute("role", "group");
          group.setAttribute("aria-label", groupName + " by section");
          const title = document.createElement("div");
          title.className = "family-title";
          title.textContent = groupName + " (" + (p.unit === "1" ? "factor" : displayUnit(p.unit)) +
            ") by angle section";
          group.appendChild(title);
          box.appendChild(group);
        }
        group.appendChild(makeParam(p, shortLabel(p), true));
      } else {
        groupName = null;
        box.appendChild(makeParam(p, p.name, false));
      }
    }
    for (const p of rows) showValue(p.name);
    setAB(S.ab);
    fillJndParams(rows);
  }

  function makeParam(p, labelText, half) {
    const [down, up] = p.keys || [];
    const row = document.createElement("div");
    row.className = half ? "param half" : "param";
    row.id = "row-" + p.name;
    row.title = p.name + ": " + p.meaning + " (" + withUnit(p.unit, p.lower) + " .. " +
      withUnit(p.unit, p.upper) + ", step " + withUnit(p.unit, p.step) +
      (down ? "; keys " + down + " down, " + up + " up" : "") +
      (p.declared ? "; declared " + withUnit(p.unit, p.declared[0]) + " .. " + withUnit(p.unit, p.declared[1]) : "") +
      ")";

    const label = document.createElement("label");
    label.htmlFor = "slider-" + p.name;
    label.textContent = labelText;

    const keys = document.createElement("span");
    keys.className = "keys";
    keys.id = "keys-" + p.name;
    keys.textContent = down ? down + "/" + up : "";
    keys.setAttribute("aria-label", down ? "keys: " + down + " down, " + up + " up" : "no keys");

    const slider = document.createElement("input");
    slider.type = "range";
    slider.id = "slider-" + p.name;
    slider.min = String(p.lower);
    slider.max = String(p.upper);
    // "any": the slider shows the exact value in force (a step grid would move the thumb
    // to its nearest point); a drag snaps to multiples of the step (or a bound) below,
    // and the arrow keys step from the value in force, as the parameter's letter keys
    slider.step = "any";
    slider.setAttribute("aria-label", p.name + " (" + displayUnit(p.unit) + ")");
    slider.setAttribute("aria-describedby", "value-" + p.name);
    const v0 = p.name in S.inForce ? S.inForce[p.name] : p.default;
    slider.value = String(v0);

    const value = document.createElement("output");
    value.className = "value";
    value.id = "value-" + p.name;
    value.htmlFor = slider.id;

    slider.addEventListener("input", () => {
      const raw = parseFloat(slider.value);
      value.textContent = withUnit(p.unit, S.dragging[p.name] ? snap(p, raw) : raw);
      value.classList.add("pending");
    });
    slider.addEventListener("keydown", (e) => {
      if (e.ctrlKey || e.metaKey || e.altKey) return;
      const dirs = { ArrowRight: 1, ArrowUp: 1, ArrowLeft: -1, ArrowDown: -1, PageUp: 5, PageDown: -5 };
      let v;
      if (e.key in dirs) {
        v = stepped(p, dirs[e.key]);
      } else if (e.key === "Home" || e.key === "End") {
        v = e.key === "Home" ? p.lower : p.upper;
      } else {
        return;
      }
      e.preventDefault();
      e.stopPropagation();
      if (v !== null && v !== currentValue(p.name)) requestSet(p.name, v, "slider");
    });
    slider.addEventListener("pointerdown", () => {
      S.dragging[p.name] = true;
    });
    const release = () => {
      delete S.dragging[p.name];
    };
    // the change event comes after pointerup (with mouseup): keep the flag until then
    slider.addEventListener("pointerup", () => setTimeout(release, 0));
    slider.addEventListener("pointercancel", release);
    slider.addEventListener("change", () => {
      // a drag lands on the step grid; a value set otherwise (a script) is taken as it is
      const raw = parseFloat(slider.value);
      const v = S.dragging[p.name] ? snap(p, raw) : clamp(raw, p.lower, p.upper);
      release();
      if (!isFinite(v)) return;
      if (v === S.inForce[p.name]) {
        showValue(p.name);
        return;
      }
      requestSet(p.name, v, "slider");
    });

    row.append(label, keys, slider, value);
    return row;
  }

  // the value readout and the slider of one parameter, from the set in force
  function showValue(name) {
    const p = S.byName[name];
    if (!p) return;
    const slider = $("slider-" + name);
    const out = $("value-" + name);
    const v = S.inForce[name];
    if (v === undefined) {
      out.textContent = "-";
      return;
    }
    slider.dataset.inForce = String(v);
    const pending = S.target[name];
    if (pending) {
      out.textContent = withUnit(p.unit, pending.value);
      out.classList.add("pending");
    } else {
      out.textContent = withUnit(p.unit, v);
      out.classList.remove("pending");
      if (!S.dragging[name]) slider.value = String(v);
    }
    const s = S.start[name];
    const changed = s !== undefined && Math.abs(s - v) > 1e-12 * Math.max(1, Math.abs(s));
    $("row-" + name).classList.toggle("changed", changed);
  }

  function requestSet(name, value, source) {
    const values = {};
    values[name] = value;
    if (send({ type: "set", values: values, source: source })) {
      S.target[name] = { value: value, at: performance.now() };
    }
    showValue(name);
  }

  function applyParams(params, source) {
    Object.assign(S.inForce, params);
    const now = performance.now();
    for (const name of Object.keys(S.target)) {
      const t = S.target[name];
      const v = S.inForce[name];
      const done = Math.abs(t.value - v) <= 1e-9 * Math.max(1, Math.abs(v));
      if (done || (source !== "slider" && source !== "key") || now - t.at > TARGET_TTL_MS) {
        delete S.target[name];
      }
    }
    for (const p of S.decl) showValue(p.name);
    latch.configure(S.inForce);
    renderAB();
    showJndUnit();
    requestCurve();
    invalidate();
  }

  function onRefused(msg) {
    const values = msg.values || {};
    const what = Object.keys(values)
      .map((n) => n + " = " + (S.byName[n] ? withUnit(S.byName[n].unit, values[n]) : fmt(values[n])))
      .join(", ");
    setMessage("Refused" + (what ? " " + what : "") + ": " + (msg.error || "no reason given"), "error");
    S.target = {};
    for (const p of S.decl) {
      delete S.dragging[p.name];
      showValue(p.name);
    }
  }

  // ---------------------------------------------------------------- keys
  function isTyping(el) {
    if (!el) return false;
    if (el.isContentEditable) return true;
    const tag = el.tagName;
    if (tag === "TEXTAREA" || tag === "SELECT") return true;
    if (tag !== "INPUT") return false;
    const type = (el.type || "text").toLowerCase();
    return !["range", "button", "checkbox", "radio", "submit", "reset", "color"].includes(type);
  }

  function onKey(e) {
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    if (isTyping(e.target)) return;
    if ($("choose-dialog").open) return;
    if (jndRunning()) {
      // a session owns the set in force: 1 and 2 answer, the parameter keys rest
      if (e.key === "1" || e.key === "2") answerJnd(Number(e.key));
      if (e.key === "1" || e.key === "2" || S.keyMap[e.key]) e.preventDefault();
      return;
    }
    const k = S.keyMap[e.key];
    if (!k) return;
    const p = S.byName[k.name];
    e.preventDefault();
    const now = performance.now();
    if (e.repeat && now - (S.lastKeyAt[e.key] || 0) < KEY_REPEAT_MS) return;
    S.lastKeyAt[e.key] = now;
    if (!(k.name in S.inForce)) return;
    const base = currentValue(k.name);
    const v = stepped(p, k.dir);
    flashKey(k.name);
    if (v === base) {
      setMessage(p.name + " is already at its " + (k.dir > 0 ? "upper" : "lower") + " bound, " +
        withUnit(p.unit, base), "info");
      return;
    }
    requestSet(k.name, v, "key");
  }

  // the value the next step starts from: the one sent and not yet confirmed, if recent,
  // else the one in force
  function currentValue(name) {
    const t = S.target[name];
    return t && performance.now() - t.at < TARGET_TTL_MS ? t.value : S.inForce[name];
  }

  // one step (dir steps, signed) from the current value, clamped to the bounds
  function stepped(p, dir) {
    const base = currentValue(p.name);
    if (base === undefined) return null;
    return clamp(round12(clamp(base + dir * p.step, p.lower, p.upper)), p.lower, p.upper);
  }

  // a dragged value onto a multiple of the step, or onto a bound when within half a step
  function snap(p, v) {
    if (!isFinite(v)) return NaN;
    if (!(p.step > 0)) return clamp(v, p.lower, p.upper);
    if (v >= p.upper - p.step / 2) return p.upper;
    if (v <= p.lower + p.step / 2) return p.lower;
    return clamp(round12(Math.round(v / p.step) * p.step), p.lower, p.upper);
  }

  function flashKey(name) {
    const el = $("keys-" + name);
    if (!el) return;
    el.classList.add("flash");
    setTimeout(() => el.classList.remove("flash"), 250);
  }

  // ---------------------------------------------------------------- A/B
  function setAB(ab) {
    S.ab = {
      A: ab.A === undefined ? S.ab.A : ab.A,
      B: ab.B === undefined ? S.ab.B : ab.B,
      active: ab.active === undefined ? S.ab.active : ab.active,
      blind: ab.blind === undefined ? S.ab.blind : !!ab.blind,
      choice: ab.choice === undefined ? S.ab.choice : ab.choice,
    };
    renderAB();
  }

  function slotLabel(slot) {
    return S.ab.blind ? (slot === "A" ? "1" : "2") : slot;
  }

  function renderAB() {
    const ab = S.ab;
    document.body.classList.toggle("blind", ab.blind);
    const blind = $("blind");
    blind.textContent = ab.blind ? "Blind: on" : "Blind: off";
    blind.setAttribute("aria-pressed", ab.blind ? "true" : "false");
    for (const slot of ["A", "B"]) {
      const s = slot.toLowerCase();
      const feel = $("feel-" + s);
      feel.textContent = "Feel " + slotLabel(slot);
      feel.classList.toggle("active", !ab.blind && ab.active === slot);
      feel.classList.toggle("empty", !ab[slot]);
      feel.setAttribute("aria-pressed", !ab.blind && ab.active === slot ? "true" : "false");
      feel.title = ab[slot] ? "Put set " + slotLabel(slot) + " on the device" : "Nothing stored in this slot yet";
      $("prefer-" + s).textContent = slotLabel(slot) + " preferred";
    }
    const bits = [];
    if (ab.active) bits.push(ab.active + " on");
    if (ab.choice) bits.push(ab.choice + " preferred");
    $("ab-active").textContent = bits.length ? "(" + bits.join(", ") + ")" : "";
    $("ab-diff").textContent = abDiff();
  }

  // which parameters differ between A and B, with their values (hidden when blind)
  function abDiff() {
    const A = S.ab.A;
    const B = S.ab.B;
    if (!A && !B) return "Nothing stored: tune a set, store it as A, tune another, store it as B.";
    if (!A || !B) return (A ? "A" : "B") + " stored; " + (A ? "B" : "A") + " empty.";
    const diffs = [];
    for (const p of S.decl) {
      const a = A[p.name];
      const b = B[p.name];
      if (a === undefined || b === undefined) continue;
      if (Math.abs(a - b) > 1e-12 * Math.max(1, Math.abs(a))) {
        diffs.push(p.name + " " + withUnit(p.unit, a) + " / " + withUnit(p.unit, b));
      }
    }
    if (!diffs.length) return "A and B are the same set.";
    const shown = diffs.slice(0, 3).join("; ");
    return "A / B: " + shown + (diffs.length > 3 ? "; and " + (diffs.length - 3) + " more" : "");
  }

  // ---------------------------------------------------------------- JND session
  // The server plays each trial (pause, interval 1, pause, interval 2) and asks for the
  // answer; blind, it sends neither the step nor the order nor whether an answer was
  // right until the session ends (evo_door/render/console/jnd_mode.py).
  const JND_UNITS = ["N", "N s/rad", "kg m", "N/rad"]; // the units a JND setting is measured in
  const SVG_NS = "http://www.w3.org/2000/svg";
  const PHASE_TEXT = {
    pause: "Pause: let go",
    1: "Interval 1",
    2: "Interval 2",
    answer: "Answer",
    answered: "...",
    fitting: "Fitting ...",
    done: "Done",
    stopped: "Stopped",
    aborted: "Ended",
  };

  function jndRunning() {
    return !!(S.jnd && S.jnd.status === "running");
  }

  function fillJndParams(rows) {
    const sel = $("jnd-param");
    const was = sel.value;
    sel.textContent = "";
    for (const p of rows) {
      if (!JND_UNITS.includes(p.unit)) continue;
      const o = document.createElement("option");
      o.value = p.name;
      o.textContent = p.name;
      sel.appendChild(o);
    }
    if (was && S.byName[was]) sel.value = was;
    showJndUnit();
  }

  function showJndUnit() {
    const p = S.byName[$("jnd-param").value];
    $("jnd-unit").textContent = p ? p.unit : "";
    const v = p ? S.inForce[p.name] : undefined;
    $("jnd-reference").placeholder = v === undefined ? "in force" : "in force: " + fmt(v);
  }

  // a number field: its value, null when empty (the server's default), NaN when not a number
  function fieldNumber(id) {
    const text = $(id).value.trim();
    return text === "" ? null : Number(text);
  }

  function startJnd() {
    const msg = {
      type: "jnd_start",
      param: $("jnd-param").value,
      method: $("jnd-method").value,
      blind: $("jnd-blind").checked,
    };
    const fields = { reference: "jnd-reference", trials: "jnd-trials", seed: "jnd-seed",
      interval_s: "jnd-interval", pause_s: "jnd-pause" };
    for (const [key, id] of Object.entries(fields)) {
      const v = fieldNumber(id);
      if (v === null) continue;
      if (!isFinite(v)) {
        setMessage(key + " " + JSON.stringify($(id).value) + ": not a number", "error");
        return;
      }
      msg[key] = v;
    }
    if (send(msg)) setMessage("Starting a JND session on " + msg.param, "info");
  }

  function answerJnd(answer) {
    if (!jndRunning() || S.jnd.phase !== "answer") return;
    if (send({ type: "jnd_answer", answer: answer })) {
      S.jnd.phase = "answered"; // until the server says what comes next
      renderJndPhase();
    }
  }

  function setJnd(msg) {
    S.jnd = msg;
    renderJnd();
  }

  function renderJndPhase() {
    const j = S.jnd;
    if (!j) return;
    const el = $("jnd-phase");
    el.textContent = PHASE_TEXT[j.phase] || j.phase;
    el.className = j.phase === "answer" ? "answer" : "";
    el.dataset.phase = j.phase;
    const open = j.status === "running" && j.phase === "answer";
    for (const k of [1, 2]) $("jnd-answer-" + k).disabled = !open;
    $("jnd-progress").textContent = "trial " + Math.min(j.trial + (j.status === "running" ? 1 : 0), j.trials) +
      " of " + j.trials;
  }

  function renderJnd() {
    const j = S.jnd;
    const view = $("jnd-view");
    if (!j) {
      view.hidden = true;
      return;
    }
    view.hidden = false;
    view.dataset.status = j.status;
    document.body.classList.toggle("jnd-blind", j.status === "running" && j.blind);
    $("jnd-title").textContent = "JND session: " + j.param + (j.participant ? ", participant " + j.participant : "") +
      (j.status === "running" ? (j.blind ? " (blind)" : "") : " (" + j.status + ")");
    $("jnd-question").textContent = "Which felt " + j.word + "?";
    $("jnd-stop").hidden = j.status !== "running";
    $("jnd-close").hidden = j.status === "running";
    renderJndPhase();
    drawTrack(j);
    drawFit(j);
    const r = $("jnd-result");
    if (j.fit) {
      const f = j.fit;
      const pct = (w) => fmt(100 * w, 3) + " %";
      r.textContent = "Weber fraction " + fmt(f.weber, 3) + " (" + pct(f.weber) + "), 95 % interval " +
        fmt(f.ci95[0], 3) + " to " + fmt(f.ci95[1], 3) + ": a JND of " + fmt(f.jnd, 3) + " " + j.unit +
        " at " + fmt(j.reference) + " " + j.unit + ", from " + f.trials + " trials" +
        (f.open_ended[0] || f.open_ended[1] ? " (the interval is open: more trials needed)" : "") +
        (j.path ? "; saved to " + j.path : "");
    } else if (j.status === "running") {
      r.textContent = "Reference " + fmt(j.reference) + " " + j.unit + ", " + j.method + ", " +
        fmt(j.interval_s) + " s intervals, " + fmt(j.pause_s) + " s pauses";
    } else {
      r.textContent = "No fit: " + j.track.length + " answers" + (j.path ? "; saved to " + j.path : "");
    }
  }

  function svgEl(parent, tag, attrs, text) {
    const el = document.createElementNS(SVG_NS, tag);
    for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, String(v));
    if (text !== undefined) el.textContent = text;
    parent.appendChild(el);
    return el;
  }

  const PLOT = { left: 52, right: 572, top: 12, bottom: 200 };

  // ticks of a log axis over [lo, hi]: 1, 2, 5 times powers of ten
  function logTicks(lo, hi) {
    const out = [];
    for (let e = Math.floor(Math.log10(lo)); e <= Math.ceil(Math.log10(hi)); e++) {
      for (const m of [1, 2, 5]) {
        const v = m * Math.pow(10, e);
        if (v >= lo && v <= hi) out.push(v);
      }
    }
    return out;
  }

  function percent(v) {
    return fmt(100 * v, 2) + " %";
  }

  function svgFrame(svg, xlabel, ylabel) {
    svg.textContent = "";
    svgEl(svg, "path", { class: "axis", d: "M" + PLOT.left + " " + PLOT.top + "V" + PLOT.bottom + "H" + PLOT.right });
    svgEl(svg, "text", { x: (PLOT.left + PLOT.right) / 2, y: 234, "text-anchor": "middle" }, xlabel);
    svgEl(svg, "text", { x: 12, y: (PLOT.top + PLOT.bottom) / 2, "text-anchor": "middle",
      transform: "rotate(-90 12 " + (PLOT.top + PLOT.bottom) / 2 + ")" }, ylabel);
  }

  function drawTrack(j) {
    const svg = $("jnd-track");
    const n = Math.max(j.trials, 1);
    const X = (k) => PLOT.left + 8 + (PLOT.right - PLOT.left - 16) * (n > 1 ? k / (n - 1) : 0.5);
    const hidden = j.track.some((t) => t.step === undefined);
    svgFrame(svg, "trial", hidden ? "(step hidden: blind)" : "step (log scale)");
    $("jnd-track-note").textContent = hidden ? "(answers only until the end)" : "(filled: correct, ring: wrong)";
    for (let k = 0; k < n; k += Math.max(1, Math.ceil(n / 10))) {
      svgEl(svg, "text", { x: X(k), y: PLOT.bottom + 16, "text-anchor": "middle" }, String(k + 1));
    }
    if (hidden) {
      const y = (PLOT.top + PLOT.bottom) / 2;
      j.track.forEach((t, k) => {
        svgEl(svg, "circle", { class: "mark blind", cx: X(k), cy: y, r: 4, "data-trial": k + 1, "data-answer": t.answer });
      });
      return;
    }
    const steps = j.track.map((t) => t.step);
    if (j.fit) steps.push(j.fit.weber);
    const lo = steps.length ? Math.min(...steps) / 1.5 : 0.01;
    const hi = steps.length ? Math.max(...steps) * 1.5 : 1;
    const Y = (v) => PLOT.bottom - (PLOT.bottom - PLOT.top) * Math.log(v / lo) / Math.log(hi / lo);
    for (const v of logTicks(lo, hi)) {
      svgEl(svg, "line", { class: "grid", x1: PLOT.left, x2: PLOT.right, y1: Y(v), y2: Y(v) });
      svgEl(svg, "text", { x: PLOT.left - 4, y: Y(v) + 4, "text-anchor": "end" }, percent(v));
    }
    if (j.fit) {
      svgEl(svg, "line", { class: "estimate", x1: PLOT.left, x2: PLOT.right, y1: Y(j.fit.weber), y2: Y(j.fit.weber) });
    }
    if (j.track.length > 1) {
      const d = j.track.map((t, k) => (k ? "L" : "M") + X(k).toFixed(1) + " " + Y(t.step).toFixed(1)).join("");
      svgEl(svg, "path", { class: "track-line", d: d });
    }
    j.track.forEach((t, k) => {
      const c = svgEl(svg, "circle", { class: "mark " + (t.correct ? "correct" : "wrong"), cx: X(k), cy: Y(t.step),
        r: 4, "data-trial": k + 1, "data-step": t.step, "data-order": t.order, "data-answer": t.answer });
      svgEl(c, "title", {}, "trial " + (k + 1) + ": step " + percent(t.step) + ", comparison in " + t.order +
        ", answered " + t.answer);
    });
  }

  function drawFit(j) {
    const svg = $("jnd-fit");
    svgFrame(svg, "step (log scale)", "P(correct)");
    // from 0: a share of correct answers below chance (few trials at a step) is shown as it is
    const Y = (p) => PLOT.bottom - (PLOT.bottom - PLOT.top) * p;
    for (const p of [0, 0.5, 0.75, 1.0]) {
      svgEl(svg, "line", { class: "grid", x1: PLOT.left, x2: PLOT.right, y1: Y(p), y2: Y(p) });
      svgEl(svg, "text", { x: PLOT.left - 4, y: Y(p) + 4, "text-anchor": "end" }, percent(p));
    }
    if (!j.fit) {
      svgEl(svg, "text", { x: (PLOT.left + PLOT.right) / 2, y: Y(0.75) - 8, "text-anchor": "middle" },
        j.status === "running" ? "fitted at the end of the session" : "no fit");
      return;
    }
    const f = j.fit;
    const xs = f.curve.step;
    const lo = xs[0];
    const hi = xs[xs.length - 1];
    const X = (v) => PLOT.left + (PLOT.right - PLOT.left) * Math.log(Math.min(Math.max(v, lo), hi) / lo) / Math.log(hi / lo);
    svgEl(svg, "rect", { class: "ci95", x: X(f.ci95[0]), y: PLOT.top, width: Math.max(1, X(f.ci95[1]) - X(f.ci95[0])),
      height: PLOT.bottom - PLOT.top });
    for (const v of logTicks(lo, hi)) {
      svgEl(svg, "text", { x: X(v), y: PLOT.bottom + 16, "text-anchor": "middle" }, percent(v));
    }
    // the answers: the share correct at each step, a dot as large as its count
    const at = {};
    for (const t of j.track) {
      const a = at[t.step] || (at[t.step] = { n: 0, k: 0 });
      a.n += 1;
      a.k += t.correct ? 1 : 0;
    }
    for (const [s, a] of Object.entries(at)) {
      svgEl(svg, "circle", { class: "observed", cx: X(Number(s)), cy: Y(a.k / a.n), r: 2 + Math.sqrt(a.n) });
    }
    const d = xs.map((x, k) => (k ? "L" : "M") + X(x).toFixed(1) + " " + Y(f.curve.p_correct[k]).toFixed(1)).join("");
    svgEl(svg, "path", { id: "jnd-fit-curve", d: d });
    svgEl(svg, "line", { class: "estimate", x1: X(f.weber), x2: X(f.weber), y1: PLOT.top, y2: PLOT.bottom });
    svgEl(svg, "text", { x: X(f.weber) + 4, y: PLOT.top + 12 }, "Weber " + fmt(f.weber, 3));
  }

  // ---------------------------------------------------------------- ticks and history
  function onTick(msg) {
    const R = S.rows;
    let last = R.t.length ? R.t[R.t.length - 1] : -Infinity;
    const rows = Array.isArray(msg.rows) ? msg.rows : [];
    if (rows.length && rows[0][0] < last - 1.0) {
      // the renderer's clock went back: a new render, start the history again
      for (const k of Object.keys(R)) R[k].length = 0;
      last = -Infinity;
      latch.reset();
    }
    let added = 0;
    for (const r of rows) {
      if (!(r[0] > last)) continue;
      pushRow(r[0], r[1], r[2], r[3]);
      last = r[0];
      added++;
    }
    const st = msg.state;
    if (!added && st && isFinite(st.t) && st.t > last && isFinite(st.theta)) {
      pushRow(st.t, st.theta, st.dtheta, st.force);
    }
    if (R.t.length) {
      const cut = R.t[R.t.length - 1] - WINDOW_S - 0.5;
      let i = 0;
      while (i < R.t.length && R.t[i] < cut) i++;
      if (i > 50) for (const k of Object.keys(R)) R[k].splice(0, i);
    }
    if (st) S.state = st;
    if (msg.health) S.health = msg.health;
    S.tickAt = performance.now();
    kick();
  }

  // the last seconds the server kept (hello): the history starts again from them, silently
  function loadHistory(rows) {
    const R = S.rows;
    for (const k of Object.keys(R)) R[k].length = 0;
    latch.reset();
    let last = -Infinity;
    for (const r of rows) {
      if (!Array.isArray(r) || !(r[0] > last)) continue;
      pushRow(r[0], r[1], r[2], r[3], true);
      last = r[0];
    }
    invalidate();
  }

  function pushRow(t, theta, dtheta, force, silent) {
    const R = S.rows;
    R.t.push(t);
    R.theta.push(theta);
    R.dtheta.push(dtheta);
    R.force.push(force);
    const ev = latch.update(theta);
    if (ev && !silent) {
      S.latchCount[ev] += 1;
      sound.click(ev);
      S.latchEvent = { kind: ev, at: performance.now() };
    }
  }

  // ---------------------------------------------------------------- latch (lock / unlock clicks)
  /* The latch angles of the haptic model (evo_door/models/haptic.py, latch_angles):
   *   closed = 90 deg; theta_0 = closed - loose_angle: the catch, where a latched door rests
   *   (the seal's seat_force holds it there); theta_1 = theta_0 - open_force / latch_stiffness
   *   - open_hold: the bottom of the unlock band, where the hook lets go while opening.
   * Unlock click: theta falls below theta_1 (the hook has let go).
   * Lock click: the closing door has come through the lock band and the snap zone and
   *   arrives on its catch, theta_0. We take "rises above theta_0 - 0.2 deg" rather than
   *   the lock band's top (theta_2) because the hook is only heard when the door reaches
   *   the catch, and because a door pushed into the snap zone and let go falls back
   *   open without locking; the 0.2 deg keeps a door resting on its catch with sensor
   *   noise from clicking again.
   * Hysteresis: the unlock threshold is at least 2 x 0.2 deg below theta_0, so a door
   *   with a very narrow unlock band does not chatter between lock and unlock.
   * No latch (open_force and close_force both 0): no clicks.
   * latch_stiffness is a device parameter (not a slider); the params messages carry the
   *   whole set, and the model's default (2000 N/rad) stands in if they do not. */
  const latch = {
    lockAt: CLOSED - 0.5 / DEG - LATCH_HYST,
    unlockAt: CLOSED - 1.0 / DEG,
    theta0: CLOSED - 0.5 / DEG,
    theta1: CLOSED - 1.0 / DEG,
    theta3: CLOSED - 2.0 / DEG,
    active: true,
    locked: null,
    lastClick: 0,
    configure(p) {
      const num = (name, dflt) => (isFinite(p[name]) ? Number(p[name]) : dflt);
      const k = num("latch_stiffness", 2000);
      const openForce = num("open_force", 20);
      const closeForce = num("close_force", 12);
      this.theta0 = CLOSED - num("loose_angle", 0.5 / DEG);
      this.theta1 = this.theta0 - (k > 0 ? openForce / k : 0) - num("open_hold", 0);
      // bottom of the lock band (the latch zoom of the force-angle plot starts below it)
      this.theta2 = this.theta1 - num("transition_angle", 0.005);
      this.theta3 = this.theta2 - (k > 0 ? closeForce / k : 0) - num("close_hold", 0);
      this.lockAt = this.theta0 - LATCH_HYST;
      this.unlockAt = Math.min(this.theta1, this.theta0 - 2 * LATCH_HYST);
      this.active = S.model.door && (openForce > 0 || closeForce > 0);
    },
    reset() {
      this.locked = null;
    },
    update(theta) {
      if (!isFinite(theta)) return null;
      if (this.locked === null) {
        this.locked = theta > this.lockAt;
        return null;
      }
      let ev = null;
      if (!this.locked && theta > this.lockAt) {
        this.locked = true;
        ev = "lock";
      } else if (this.locked && theta < this.unlockAt) {
        this.locked = false;
        ev = "unlock";
      }
      return this.active ? ev : null;
    },
  };

  // ---------------------------------------------------------------- sound (Web Audio, generated)
  const sound = {
    ctx: null,
    on: false,
    master: null,
    slideGain: null,
    slideFilter: null,
    noise: null,
    level: 0,
    enable() {
      const AC = window.AudioContext || window.webkitAudioContext;
      if (!AC) {
        setMessage("This browser has no Web Audio: no sound", "error");
        return false;
      }
      if (!this.ctx) {
        const ctx = new AC();
        this.ctx = ctx;
        // two seconds of white noise, looped, for the sliding sound and the clicks
        const n = Math.floor(ctx.sampleRate * 2);
        const buf = ctx.createBuffer(1, n, ctx.sampleRate);
        const d = buf.getChannelData(0);
        for (let i = 0; i < n; i++) d[i] = Math.random() * 2 - 1;
        this.noise = buf;
        this.master = ctx.createGain();
        this.master.gain.value = 0;
        this.master.connect(ctx.destination);
        const src = ctx.createBufferSource();
        src.buffer = buf;
        src.loop = true;
        this.slideFilter = ctx.createBiquadFilter();
        this.slideFilter.type = "bandpass";
        this.slideFilter.frequency.value = 600;
        this.slideFilter.Q.value = 0.7;
        this.slideGain = ctx.createGain();
        this.slideGain.gain.value = 0;
        src.connect(this.slideFilter).connect(this.slideGain).connect(this.master);
        src.start();
      }
      this.ctx.resume();
      this.master.gain.setTargetAtTime(0.9, this.ctx.currentTime, 0.02);
      this.on = true;
      return true;
    },
    disable() {
      this.on = false;
      if (this.ctx) {
        this.master.gain.setTargetAtTime(0, this.ctx.currentTime, 0.01);
        setTimeout(() => {
          if (!this.on && this.ctx) this.ctx.suspend();
        }, 100);
      }
    },
    // a latch click: a few ms of band-passed noise and a short decaying tone;
    // the lock is lower and heavier (the door lands on its catch), the unlock higher
    click(kind) {
      if (!this.on || !this.ctx) return;
      const ctx = this.ctx;
      const now = ctx.currentTime;
      if (now - latch.lastClick < 0.05) return;
      latch.lastClick = now;
      const lock = kind === "lock";
      const src = ctx.createBufferSource();
      src.buffer = this.noise;
      const bp = ctx.createBiquadFilter();
      bp.type = "bandpass";
      bp.frequency.value = lock ? 1800 : 3200;
      bp.Q.value = 3;
      const g = ctx.createGain();
      g.gain.setValueAtTime(0, now);
      g.gain.linearRampToValueAtTime(lock ? 0.9 : 0.7, now + 0.001);
      g.gain.exponentialRampToValueAtTime(0.001, now + (lock ? 0.012 : 0.008));
      src.connect(bp).connect(g).connect(this.master);
      src.start(now, Math.random());
      src.stop(now + 0.03);
      const osc = ctx.createOscillator();
      osc.type = "sine";
      osc.frequency.value = lock ? 190 : 620;
      const og = ctx.createGain();
      og.gain.setValueAtTime(0, now);
      og.gain.linearRampToValueAtTime(lock ? 0.6 : 0.3, now + 0.001);
      og.gain.exponentialRampToValueAtTime(0.001, now + (lock ? 0.07 : 0.035));
      osc.connect(og).connect(this.master);
      osc.start(now);
      osc.stop(now + 0.1);
    },
    // the sliding sound: loudness follows |speed|, 0 at rest, full at SLIDE_FULL_DEG_S
    slide(speedDegS) {
      if (!this.on || !this.ctx) return;
      const x = clamp(Math.abs(speedDegS) / SLIDE_FULL_DEG_S, 0, 1);
      const level = isFinite(x) ? x : 0;
      if (Math.abs(level - this.level) < 0.005) return;
      this.level = level;
      const now = this.ctx.currentTime;
      this.slideGain.gain.setTargetAtTime(0.35 * level, now, 0.06);
      this.slideFilter.frequency.setTargetAtTime(350 + 900 * level, now, 0.06);
    },
  };

  // the sliding sound's speed in deg/s: the door's own; a mechanism's as the door's
  // quarter turn is to its stroke (the same loudness at the same fraction a second)
  function slideSpeed(dtheta) {
    if (S.model.door) return dtheta * DEG;
    return (dtheta / (S.model.range[1] - S.model.range[0])) * CLOSED * DEG;
  }

  // ---------------------------------------------------------------- curve
  let curveSeq = 0;
  let curveTimer = null;
  function requestCurve() {
    clearTimeout(curveTimer);
    curveTimer = setTimeout(fetchCurve, 80);
  }

  function fetchCurve() {
    const seq = ++curveSeq;
    fetch(withToken("/api/curve"), { cache: "no-store" })
      .then((r) => {
        if (!r.ok) throw new Error("GET /api/curve: HTTP " + r.status);
        return r.json();
      })
      .then((c) => {
        if (seq !== curveSeq) return; // a newer request is on its way
        c.seq = seq;
        S.curve = c;
        invalidate();
      })
      .catch((err) => {
        if (seq === curveSeq) setMessage(String(err.message || err), "error");
      });
  }

  // ---------------------------------------------------------------- drawing helpers
  function fitCanvas(c) {
    const r = c.getBoundingClientRect();
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(r.width * dpr));
    const h = Math.max(1, Math.round(r.height * dpr));
    if (c.width !== w || c.height !== h) {
      c.width = w;
      c.height = h;
    }
    const ctx = c.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, r.width, r.height);
    return { ctx: ctx, w: r.width, h: r.height };
  }

  // round tick positions covering [lo, hi]
  function niceStep(lo, hi, count) {
    const raw = (hi - lo) / Math.max(1, count);
    const p = Math.pow(10, Math.floor(Math.log10(raw)));
    const m = raw / p;
    return (m >= 5 ? 10 : m >= 2 ? 5 : m >= 1 ? 2 : 1) * p;
  }

  // [lo, hi] widened to whole ticks: an axis that changes only when the data leave it
  function niceRange(r, count) {
    const step = niceStep(r[0], r[1], count);
    return [Math.floor(r[0] / step + 1e-9) * step, Math.ceil(r[1] / step - 1e-9) * step];
  }

  // An offscreen canvas holding what changes seldom (axes, grid, labels, the model's
  // curves), drawn again only when its key changes; each frame copies it and draws
  // only the live data over it.
  const layers = {};
  function layer(name, w, h, key, draw) {
    const dpr = window.devicePixelRatio || 1;
    let L = layers[name];
    if (!L) L = layers[name] = { canvas: document.createElement("canvas"), key: null };
    const cw = Math.max(1, Math.round(w * dpr));
    const ch = Math.max(1, Math.round(h * dpr));
    const fullKey = cw + "x" + ch + "|" + key;
    if (L.key !== fullKey) {
      L.canvas.width = cw;
      L.canvas.height = ch;
      const ctx = L.canvas.getContext("2d");
      ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      ctx.clearRect(0, 0, w, h);
      draw(ctx);
      L.key = fullKey;
    }
    return L.canvas;
  }

  function mapping(box, xr, yr) {
    const { x, y, w, h } = box;
    return {
      X: (v) => x + ((v - xr[0]) / (xr[1] - xr[0])) * w,
      Y: (v) => y + h - ((v - yr[0]) / (yr[1] - yr[0])) * h,
    };
  }

  function niceTicks(lo, hi, count) {
    if (!(hi > lo)) return [lo];
    const step = niceStep(lo, hi, count);
    const ticks = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) {
      ticks.push(Math.abs(v) < step * 1e-9 ? 0 : v);
    }
    return ticks;
  }

  function range(arrays, pad, minSpan) {
    let lo = Infinity;
    let hi = -Infinity;
    for (const a of arrays) {
      for (const v of a) {
        if (!isFinite(v)) continue;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
      }
    }
    if (!isFinite(lo)) return [-1, 1];
    if (hi - lo < minSpan) {
      const c = (hi + lo) / 2;
      lo = c - minSpan / 2;
      hi = c + minSpan / 2;
    }
    const d = (hi - lo) * pad;
    return [lo - d, hi + d];
  }

  const COLORS = {
    ink: "#1d2330",
    grid: "#e4e7ec",
    axis: "#98a2b3",
    muted: "#667085",
    opening: "#c2410c",
    closing: "#1f5fbf",
    trace: "#111827",
    angle: "#1f5fbf",
    speed: "#0f766e",
    force: "#b42318",
    latch: "#f59e0b",
  };

  // axes box with ticks and labels; returns the mapping functions
  function axes(ctx, box, xr, yr, xlabel, ylabel, opts) {
    const o = opts || {};
    const { x, y, w, h } = box;
    const X = (v) => x + ((v - xr[0]) / (xr[1] - xr[0])) * w;
    const Y = (v) => y + h - ((v - yr[0]) / (yr[1] - yr[0])) * h;
    ctx.font = "11px system-ui, sans-serif";
    ctx.lineWidth = 1;
    ctx.strokeStyle = COLORS.grid;
    ctx.fillStyle = COLORS.muted;
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const v of niceTicks(yr[0], yr[1], o.yTicks || 4)) {
      const py = Math.round(Y(v)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(x, py);
      ctx.lineTo(x + w, py);
      ctx.stroke();
      ctx.fillText(fmt(v, 3), x - 4, py);
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const v of niceTicks(xr[0], xr[1], o.xTicks || 6)) {
      const px = Math.round(X(v)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(px, y);
      ctx.lineTo(px, y + h);
      ctx.stroke();
      if (!o.noXLabels) ctx.fillText(fmt(v, 3), px, y + h + 2);
    }
    ctx.strokeStyle = COLORS.axis;
    ctx.strokeRect(x + 0.5, y + 0.5, w, h);
    ctx.fillStyle = COLORS.ink;
    if (xlabel) {
      ctx.textAlign = "right";
      ctx.textBaseline = "bottom";
      ctx.fillText(xlabel, x + w, y + h + 26);
    }
    if (ylabel) {
      ctx.textAlign = "left";
      ctx.textBaseline = "top";
      ctx.fillText(ylabel, x + 4, y + 2);
    }
    return { X: X, Y: Y };
  }

  // a series whose x rises, drawn with at most two points (its min and max) per pixel
  // column: the same picture as every point, spikes included, for much less drawing
  function seriesLine(ctx, xs, ys, X, Y) {
    const n = xs.length;
    ctx.beginPath();
    let col = null;
    let lo = 0;
    let hi = 0;
    let first = true;
    const flush = () => {
      if (col === null) return;
      if (first) {
        ctx.moveTo(col, Y(lo));
        first = false;
      } else {
        ctx.lineTo(col, Y(lo));
      }
      if (hi !== lo) ctx.lineTo(col, Y(hi));
    };
    for (let i = 0; i < n; i++) {
      const b = ys[i];
      if (!isFinite(xs[i]) || !isFinite(b)) continue;
      const c = Math.round(X(xs[i]));
      if (c !== col) {
        flush();
        col = c;
        lo = b;
        hi = b;
      } else if (b < lo) {
        lo = b;
      } else if (b > hi) {
        hi = b;
      }
    }
    flush();
    ctx.stroke();
  }

  function polyline(ctx, xs, ys, X, Y, from, to) {
    ctx.beginPath();
    let pen = false;
    for (let i = from || 0; i < (to === undefined ? xs.length : to); i++) {
      const a = xs[i];
      const b = ys[i];
      if (!isFinite(a) || !isFinite(b)) {
        pen = false;
        continue;
      }
      if (pen) ctx.lineTo(X(a), Y(b));
      else ctx.moveTo(X(a), Y(b));
      pen = true;
    }
    ctx.stroke();
  }

  // ---------------------------------------------------------------- the door
  function displayedState() {
    const st = S.state;
    const R = S.rows;
    let theta;
    let dtheta;
    let force;
    if (st && isFinite(st.theta)) {
      theta = st.theta;
      dtheta = st.dtheta;
      force = st.force;
    } else if (R.t.length) {
      const i = R.t.length - 1;
      theta = R.theta[i];
      dtheta = R.dtheta[i];
      force = R.force[i];
    } else {
      return null;
    }
    // between two ticks (about 33 ms apart), move the drawing on with the speed
    const age = Math.min((performance.now() - S.tickAt) / 1000, 0.05);
    if (isFinite(dtheta)) {
      const [lo, hi] = S.model.range;
      const pad = S.model.door ? 0.05 : 0.1 * (hi - lo);
      theta = S.model.door ? clamp(theta + dtheta * age, -0.05, CLOSED + 0.05) : clamp(theta + dtheta * age, lo - pad, hi + pad);
    }
    return { theta: theta, dtheta: dtheta, force: force };
  }

  function drawDoor(ds) {
    if (!S.model.door) {
      drawStroke(ds);
      return;
    }
    const { ctx, w, h } = fitCanvas($("door"));
    const m = 16;
    const hx = Math.max(m + 30, w * 0.18);
    // room for the scale's labels right of the open door and above the closed one
    const L = Math.max(40, Math.min(w - hx - 52, h - 2 * m - 24));
    const hy = h - m - 4;
    const key = [latch.active, latch.theta0, latch.theta1].join();
    ctx.drawImage(layer("door", w, h, key, (c) => drawDoorBack(c, w, h, L, hx, hy)), 0, 0, w, h);
    if (!ds) {
      ctx.fillStyle = COLORS.muted;
      ctx.font = "11px system-ui, sans-serif";
      ctx.textAlign = "center";
      ctx.fillText("waiting for the renderer", w / 2, h / 2);
      return;
    }
    drawDoorPanel(ctx, ds, w, L, hx, hy);
  }

  // what does not move: tub, floor, angle scale, latch band, hinge
  function drawDoorBack(ctx, w, h, L, hx, hy) {
    // the tub, behind the closed door (left of the hinge)
    ctx.strokeStyle = "#c0c6d0";
    ctx.lineWidth = 1;
    ctx.setLineDash([4, 3]);
    ctx.strokeRect(4.5, hy - L + 0.5, hx - 10, L);
    ctx.setLineDash([]);
    ctx.fillStyle = COLORS.muted;
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    if (hx > 50) ctx.fillText("tub", (hx - 6) / 2, hy - L / 2);
    // floor
    ctx.strokeStyle = COLORS.axis;
    ctx.beginPath();
    ctx.moveTo(0, hy + 8.5);
    ctx.lineTo(w, hy + 8.5);
    ctx.stroke();
    // angle scale: arc, ticks every 15 deg
    const R = L + 10;
    ctx.strokeStyle = COLORS.grid;
    ctx.beginPath();
    ctx.arc(hx, hy, R, -Math.PI / 2, 0);
    ctx.stroke();
    ctx.fillStyle = COLORS.muted;
    for (let d = 0; d <= 90; d += 15) {
      const a = d / DEG;
      const c = Math.cos(a);
      const s = Math.sin(a);
      ctx.strokeStyle = COLORS.axis;
      ctx.beginPath();
      ctx.moveTo(hx + R * c, hy - R * s);
      ctx.lineTo(hx + (R + 5) * c, hy - (R + 5) * s);
      ctx.stroke();
      if (d % 45 === 0) {
        ctx.textAlign = d === 90 ? "center" : "left";
        ctx.textBaseline = d === 90 ? "bottom" : "middle";
        ctx.fillText(d + " deg", hx + (R + 8) * c, hy - (R + 8) * s);
      }
    }
    // the latch: unlock band from theta_1 up to the catch theta_0
    if (latch.active) {
      ctx.strokeStyle = COLORS.latch;
      ctx.lineWidth = 5;
      ctx.beginPath();
      ctx.arc(hx, hy, R, -latch.theta0, -Math.max(latch.theta1, latch.theta0 - 10 / DEG));
      ctx.stroke();
      ctx.lineWidth = 1;
    }
    // hinge
    ctx.fillStyle = COLORS.ink;
    ctx.beginPath();
    ctx.arc(hx, hy, 5, 0, 2 * Math.PI);
    ctx.fill();
  }

  // the door at its angle, its handle, the user's force, the numbers
  function drawDoorPanel(ctx, ds, w, L, hx, hy) {
    const th = ds.theta;
    const u = [Math.cos(th), -Math.sin(th)]; // along the door, hinge -> top edge
    const n = [Math.sin(th), Math.cos(th)]; // outer face (toward the user when closed)
    const ex = hx + L * u[0];
    const ey = hy + L * u[1];
    // the panel
    ctx.strokeStyle = latch.locked ? "#344054" : COLORS.ink;
    ctx.lineCap = "round";
    ctx.lineWidth = 12;
    ctx.beginPath();
    ctx.moveTo(hx, hy);
    ctx.lineTo(ex, ey);
    ctx.stroke();
    ctx.lineCap = "butt";
    // the handle on the outer face, near the top edge
    const hp = 0.9 * L;
    const hb = [hx + hp * u[0] + 8 * n[0], hy + hp * u[1] + 8 * n[1]];
    ctx.strokeStyle = "#98a2b3";
    ctx.lineWidth = 5;
    ctx.beginPath();
    ctx.moveTo(hb[0] - 10 * u[0], hb[1] - 10 * u[1]);
    ctx.lineTo(hb[0] + 6 * u[0], hb[1] + 6 * u[1]);
    ctx.stroke();
    // the user's force along the handle's path, + toward closing
    if (isFinite(ds.force) && Math.abs(ds.force) > 0.2) {
      const t = [-Math.sin(th), -Math.cos(th)]; // d(position)/d(theta), toward closing
      const len = clamp(ds.force * 2.5, -70, 70);
      const ax = hb[0] + 10 * n[0];
      const ay = hb[1] + 10 * n[1];
      const bx = ax + len * t[0];
      const by = ay + len * t[1];
      ctx.strokeStyle = COLORS.force;
      ctx.fillStyle = COLORS.force;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(ax, ay);
      ctx.lineTo(bx, by);
      ctx.stroke();
      const sgn = Math.sign(len);
      const hx2 = bx - sgn * 7 * t[0];
      const hy2 = by - sgn * 7 * t[1];
      ctx.beginPath();
      ctx.moveTo(bx, by);
      ctx.lineTo(hx2 + 4 * n[0], hy2 + 4 * n[1]);
      ctx.lineTo(hx2 - 4 * n[0], hy2 - 4 * n[1]);
      ctx.closePath();
      ctx.fill();
    }
    const x0 = readout(ctx, w, "angle " + fixed(ds.theta * DEG, 1) + " deg",
      (isFinite(ds.dtheta) ? fixed(ds.dtheta * DEG, 1) : "-") + " deg/s", ds.force);
    if (latch.active && latch.locked !== null) {
      const recent = S.latchEvent && performance.now() - S.latchEvent.at < 600;
      ctx.fillStyle = recent ? "#b54708" : COLORS.muted;
      ctx.fillText((latch.locked ? "latched" : "unlatched") + (recent ? " (click)" : ""), x0, 49);
    }
  }

  // a mechanism's handle (not the haptic door): its stroke from open (left) to closed
  // (right) with a scale in its unit, the handle as a block, the user's force, the numbers
  function drawStroke(ds) {
    const { ctx, w, h } = fitCanvas($("door"));
    const [lo, hi] = S.model.range;
    const hk = handleScale();
    const u = handleUnit();
    const x0 = 36;
    const x1 = Math.max(x0 + 20, w - 36);
    const y = Math.round(h * 0.55) + 0.5;
    const X = (q) => x0 + ((q - lo) / (hi - lo)) * (x1 - x0);
    ctx.strokeStyle = COLORS.axis;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x0, y);
    ctx.lineTo(x1, y);
    ctx.stroke();
    ctx.lineWidth = 1;
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillStyle = COLORS.muted;
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const v of niceTicks(lo * hk, hi * hk, 5)) {
      const px = Math.round(X(v / hk)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(px, y + 3);
      ctx.lineTo(px, y + 8);
      ctx.stroke();
      ctx.fillText(fmt(v, 3) + " " + u, px, y + 10);
    }
    ctx.textBaseline = "bottom";
    ctx.fillText("open", x0, y - 22);
    ctx.fillText("closed", x1, y - 22);
    if (!ds) {
      ctx.fillText("waiting for the renderer", w / 2, y - 40);
      return;
    }
    const px = X(clamp(ds.theta, lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo)));
    ctx.fillStyle = COLORS.ink;
    ctx.fillRect(px - 9, y - 14, 18, 28);
    // the user's force along the stroke, + toward closing (right)
    if (isFinite(ds.force) && Math.abs(ds.force) > 0.2) {
      const len = clamp(ds.force * 2.5, -70, 70);
      const ay = y - 24;
      ctx.strokeStyle = COLORS.force;
      ctx.fillStyle = COLORS.force;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(px, ay);
      ctx.lineTo(px + len, ay);
      ctx.stroke();
      const sgn = Math.sign(len);
      ctx.beginPath();
      ctx.moveTo(px + len, ay);
      ctx.lineTo(px + len - sgn * 7, ay - 4);
      ctx.lineTo(px + len - sgn * 7, ay + 4);
      ctx.closePath();
      ctx.fill();
    }
    const d = handleDigits();
    readout(ctx, w, handleWord() + " " + fixed(ds.theta * hk, d) + " " + u,
      (isFinite(ds.dtheta) ? fixed(ds.dtheta * hk, d) : "-") + " " + u + "/s", ds.force);
  }

  // the numbers at the top right of the door or the stroke, a line each: the position
  // and the speed (as given, with their units), the force in N; returns their right
  // edge, for a line more
  function readout(ctx, w, position, speed, force) {
    ctx.fillStyle = COLORS.ink;
    ctx.font = "12px system-ui, sans-serif";
    ctx.textAlign = "right";
    ctx.textBaseline = "top";
    const x = w - 6;
    ctx.fillText(position, x, 4);
    ctx.fillText("speed " + speed, x, 19);
    ctx.fillText("force " + (isFinite(force) ? fixed(force, 1) : "-") + " N", x, 34);
    return x;
  }

  // ---------------------------------------------------------------- force against angle
  function drawForceAngle() {
    const { ctx, w, h } = fitCanvas($("force-angle"));
    const c = S.curve;
    const R = S.rows;
    const n = R.t.length;
    const tEnd = n ? R.t[n - 1] : 0;
    let i0 = 0;
    while (i0 < n && R.t[i0] < tEnd - WINDOW_S) i0++;
    const hk = handleScale();
    const thDeg = [];
    const f = [];
    for (let i = i0; i < n; i++) {
      thDeg.push(R.theta[i] * hk);
      f.push(R.force[i]);
    }
    const cx = c && Array.isArray(c.theta) ? c.theta.map((v) => v * hk) : c && c.theta_deg ? c.theta_deg : [];
    let xr;
    if (S.zoomLatch && S.model.door) {
      // the latch: from below the lock band to just past closed
      xr = [Math.min(latch.theta3 * DEG, 89) - 1, CLOSED * DEG + 0.5];
    } else if (S.model.door) {
      xr = [Math.min(-2, cx.length ? cx[0] : 0), Math.max(92, cx.length ? cx[cx.length - 1] + 2 : 0)];
    } else {
      // the stroke and a twentieth of it beyond each end (where the stops push)
      const lo = S.model.range[0] * hk;
      const hi = S.model.range[1] * hk;
      const pad = 0.05 * (hi - lo);
      xr = [Math.min(lo, cx.length ? cx[0] : lo) - pad, Math.max(hi, cx.length ? cx[cx.length - 1] : hi) + pad];
    }
    const inside = (xs, ys) => ys.filter((_, i) => xs[i] >= xr[0] && xs[i] <= xr[1]);
    const yr = niceRange(
      range([c ? inside(cx, c.opening || []) : [], c ? inside(cx, c.closing || []) : [], inside(thDeg, f)], 0.05, 4),
      5
    );
    const box = { x: 42, y: 8, w: w - 50, h: h - 40 };
    if (box.w < 20 || box.h < 20) return;
    const key = [xr, yr, c ? c.seq : 0, S.model.name].join();
    ctx.drawImage(layer("force-angle", w, h, key, (g) => drawForceAngleBack(g, box, xr, yr, c, cx)), 0, 0, w, h);
    const { X, Y } = mapping(box, xr, yr);
    ctx.save();
    ctx.beginPath();
    ctx.rect(box.x, box.y, box.w, box.h);
    ctx.clip();
    // the live trace: older points fainter
    const m = thDeg.length;
    if (m > 1) {
      const parts = 6;
      ctx.strokeStyle = COLORS.trace;
      ctx.lineWidth = 1.3;
      for (let k = 0; k < parts; k++) {
        const a = Math.floor((k * (m - 1)) / parts);
        const b = Math.floor(((k + 1) * (m - 1)) / parts) + 1;
        ctx.globalAlpha = 0.15 + (0.85 * (k + 1)) / parts;
        polyline(ctx, thDeg, f, X, Y, a, b);
      }
      ctx.globalAlpha = 1;
    }
    if (m > 0) {
      ctx.fillStyle = COLORS.force;
      ctx.beginPath();
      ctx.arc(X(thDeg[m - 1]), Y(f[m - 1]), 4, 0, 2 * Math.PI);
      ctx.fill();
    }
    ctx.restore();
  }

  function drawForceAngleBack(ctx, box, xr, yr, c, cx) {
    const xlabel = handleWord() + " (" + handleUnit() + ")";
    const { X, Y } = axes(ctx, box, xr, yr, xlabel, "force (N), + toward closing", { xTicks: 6 });
    ctx.save();
    ctx.beginPath();
    ctx.rect(box.x, box.y, box.w, box.h);
    ctx.clip();
    if (yr[0] < 0 && yr[1] > 0) {
      ctx.strokeStyle = COLORS.axis;
      ctx.beginPath();
      ctx.moveTo(box.x, Math.round(Y(0)) + 0.5);
      ctx.lineTo(box.x + box.w, Math.round(Y(0)) + 0.5);
      ctx.stroke();
    }
    if (c && cx.length) {
      ctx.lineWidth = 1.5;
      ctx.strokeStyle = COLORS.opening;
      seriesLine(ctx, cx, c.opening || [], X, Y);
      ctx.strokeStyle = COLORS.closing;
      seriesLine(ctx, cx, c.closing || [], X, Y);
    }
    ctx.restore();
    // legend
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "left";
    ctx.textBaseline = "middle";
    const lx = box.x + 8;
    let ly = box.y + 22;
    const items = [
      [COLORS.opening, "model, opening"],
      [COLORS.closing, "model, closing"],
      [COLORS.trace, "user, last " + WINDOW_S + " s"],
    ];
    for (const [col, text] of items) {
      ctx.strokeStyle = col;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(lx, ly);
      ctx.lineTo(lx + 16, ly);
      ctx.stroke();
      ctx.fillStyle = COLORS.ink;
      ctx.fillText(text, lx + 20, ly);
      ly += 13;
    }
    if (!c) {
      ctx.fillStyle = COLORS.muted;
      ctx.fillText("model curve: waiting for /api/curve", lx, ly + 4);
    }
  }

  // ---------------------------------------------------------------- strip chart
  const STRIP = [
    { label: "angle (deg)", color: COLORS.angle, min: 5, digits: 1, unit: "deg" },
    { label: "speed (deg/s)", color: COLORS.speed, min: 10, digits: 1, unit: "deg/s" },
    { label: "force (N)", color: COLORS.force, min: 2, digits: 1, unit: "N" },
  ];

  // the strip's traces: the door's in degrees, a mechanism's handle in its unit
  function stripTraces() {
    if (S.model.door) return STRIP;
    const u = handleUnit();
    const span = (S.model.range[1] - S.model.range[0]) * handleScale();
    const d = handleDigits();
    return [
      { label: handleWord() + " (" + u + ")", color: COLORS.angle, min: 0.05 * span, digits: d, unit: u },
      { label: "speed (" + u + "/s)", color: COLORS.speed, min: 0.1 * span, digits: d, unit: u + "/s" },
      STRIP[2],
    ];
  }

  function drawStrip() {
    const STRIP = stripTraces();
    const hk = handleScale();
    const { ctx, w, h } = fitCanvas($("strip"));
    const R = S.rows;
    const n = R.t.length;
    const tEnd = n ? R.t[n - 1] : 0;
    let i0 = 0;
    while (i0 < n && R.t[i0] < tEnd - WINDOW_S) i0++;
    const rel = [];
    const data = [[], [], []];
    for (let i = i0; i < n; i++) {
      rel.push(R.t[i] - tEnd);
      data[0].push(R.theta[i] * hk);
      data[1].push(R.dtheta[i] * hk);
      data[2].push(R.force[i]);
    }
    const top = 8;
    const gap = 10;
    const ph = (h - top - 30 - gap * 2) / 3;
    if (ph < 20 || w < 80) return;
    const xr = [-WINDOW_S, 0];
    const boxes = STRIP.map((_, k) => ({ x: 46, y: top + k * (ph + gap), w: w - 54, h: ph }));
    const yrs = STRIP.map((tr, k) => niceRange(range([data[k]], 0.05, tr.min), 3));
    const back = layer("strip", w, h, yrs.join("|") + S.model.name, (g) => {
      STRIP.forEach((tr, k) => {
        const last = k === STRIP.length - 1;
        axes(g, boxes[k], xr, yrs[k], last ? "time (s), 0 = now" : "", tr.label, {
          noXLabels: !last,
          yTicks: 3,
          xTicks: 5,
        });
      });
    });
    ctx.drawImage(back, 0, 0, w, h);
    STRIP.forEach((tr, k) => {
      const box = boxes[k];
      const { X, Y } = mapping(box, xr, yrs[k]);
      ctx.save();
      ctx.beginPath();
      ctx.rect(box.x, box.y, box.w, box.h);
      ctx.clip();
      ctx.strokeStyle = tr.color;
      ctx.lineWidth = 1.5;
      seriesLine(ctx, rel, data[k], X, Y);
      ctx.restore();
      if (data[k].length) {
        const v = data[k][data[k].length - 1];
        ctx.fillStyle = tr.color;
        ctx.font = "bold 12px system-ui, sans-serif";
        ctx.textAlign = "right";
        ctx.textBaseline = "top";
        ctx.fillText(fixed(v, tr.digits) + " " + tr.unit, box.x + box.w - 4, box.y + 2);
      }
    });
  }

  // ---------------------------------------------------------------- health
  // the health's watchdog: "" while it has not tripped, else why it tripped
  function watchdogState(reason) {
    return reason ? { tripped: true, text: "TRIPPED: " + reason } : { tripped: false, text: "ok" };
  }

  function setField(id, text, bad) {
    const el = $(id);
    if (el.textContent !== text) el.textContent = text;
    el.title = text;
    el.classList.toggle("bad", !!bad);
  }

  // The health fields are those of the control port's health answer, which the server
  // passes on in hello and every tick (tests/test_console_server.py checks that every
  // field read from hl here is sent).
  function updateHealth() {
    const hl = S.health || {};
    const st = S.state || {};
    const age = (performance.now() - S.tickAt) / 1000;
    const stale = S.connected && S.tickAt > 0 && age > STALE_TICK_S;
    const status = hl.status || st.status || (S.connected ? "waiting" : "-");
    const onTime = Number(hl.on_time_fraction);
    const late = !isFinite(onTime) || onTime < ON_TIME_MIN;
    const wd = watchdogState(hl.watchdog);
    // stale: the last status is not the loop's now, so it is not shown as if it were
    const shown = !S.connected ? "no connection" : stale ? "no data for " + age.toFixed(0) + " s" : status;
    setField("h-status", shown, !S.connected || stale);
    setField("h-rate", isFinite(hl.rate_hz) ? fmt(hl.rate_hz) + " Hz" : "-", false);
    setField("h-ontime", isFinite(onTime) ? (onTime * 100).toFixed(3) + " %" : "-", late);
    const missed = hl.missed_cycles;
    const saturated = hl.saturated_cycles;
    setField("h-missed", isFinite(missed) ? String(missed) : "-", missed > 0);
    if (isFinite(hl.cycles)) $("h-missed").title = missed + " of " + hl.cycles + " cycles";
    setField("h-late", isFinite(hl.lateness_p99_s) ? fmt(hl.lateness_p99_s * 1e3, 3) + " ms" : "-", false);
    setField("h-faults", isFinite(hl.faults) ? String(hl.faults) : "-", hl.faults > 0);
    setField("h-saturated", isFinite(saturated) ? saturated + " cycles" : "-", false);
    setField("h-watchdog", S.health ? wd.text : "-", wd.tripped);
    setField(
      "h-door",
      latch.locked === null || !latch.active ? "-" : latch.locked ? "latched" : "unlatched",
      false
    );
    const warn = !S.connected || stale || !S.health || late || wd.tripped;
    $("health").classList.toggle("warn", warn);
  }

  // ---------------------------------------------------------------- frame loop
  // Frames run only when there is something to draw: a tick, a change of the set, the
  // curve, the zoom or the size schedule one (invalidate / kick), and a moving door
  // keeps them coming at display rate (between two ticks it is moved on with its
  // speed). The door is redrawn when its picture changes, the plots when rows came, at
  // most CHART_HZ times a second: the browser shares the machine with the servo loop.
  const CHART_HZ = 10;
  const FRAME_HZ = 30; // a moving door is redrawn this often: display rate, at half the browser's
  const HEALTH_MS = 250;
  let framePending = false;
  let lastTickDrawn = -1;
  let lastChart = 0;
  let lastDoorKey = "";

  function kick() {
    if (!framePending) {
      framePending = true;
      requestAnimationFrame(frame);
    }
  }

  function invalidate() {
    S.dirty = true;
    kick();
  }

  function frame() {
    framePending = false;
    const now = performance.now();
    const ds = displayedState();
    const recentClick = S.latchEvent ? now - S.latchEvent.at < 600 : false;
    const doorKey = ds
      ? [ds.theta.toFixed(4), isFinite(ds.force) ? ds.force.toFixed(1) : "", latch.locked, recentClick].join()
      : "none";
    const dirty = S.dirty;
    S.dirty = false;
    if (dirty || doorKey !== lastDoorKey) {
      lastDoorKey = doorKey;
      drawDoor(ds);
    }
    let chartsWaiting = false;
    if (dirty || S.tickAt !== lastTickDrawn) {
      if (dirty || now - lastChart >= 1000 / CHART_HZ) {
        lastTickDrawn = S.tickAt;
        lastChart = now;
        drawForceAngle();
        drawStrip();
      } else {
        chartsWaiting = true;
      }
    }
    const age = now - S.tickAt;
    const moving = ds && isFinite(ds.dtheta) && Math.abs(ds.dtheta) > 1e-3 && age < 60;
    sound.slide(S.connected && age < 500 && ds && isFinite(ds.dtheta) ? slideSpeed(ds.dtheta) : 0);
    if (moving || chartsWaiting || recentClick) {
      // the next frame a display period later, not at the browser's own 60 Hz: the
      // browser shares the machine's two cores with the servo loop
      setTimeout(kick, 1000 / FRAME_HZ);
    }
  }

  // the health panel and the sliding sound's silence do not wait for frames
  function slowTimer() {
    updateHealth();
    if (!S.connected || performance.now() - S.tickAt > 500) sound.slide(0);
  }

  // ---------------------------------------------------------------- controls
  function wire() {
    document.addEventListener("keydown", onKey);
    $("undo").addEventListener("click", () => send({ type: "undo" }));
    $("reset").addEventListener("click", () => send({ type: "reset" }));
    $("save").addEventListener("click", () => {
      const stem = $("save-name").value.trim() || "chosen";
      $("save-name").value = stem;
      if (send({ type: "save", name: stem })) $("saved-path").textContent = "Saving " + stem + " ...";
    });
    $("save-name").addEventListener("keydown", (e) => {
      if (e.key === "Enter") $("save").click();
    });
    for (const slot of ["A", "B"]) {
      const s = slot.toLowerCase();
      $("store-" + s).addEventListener("click", () => {
        if (send({ type: "ab_store", slot: slot })) setMessage("Stored the set in force as " + slot, "info");
      });
      $("feel-" + s).addEventListener("click", () => {
        send({ type: "ab_switch", slot: slot });
      });
      $("prefer-" + s).addEventListener("click", () => {
        if (send({ type: "ab_choice", slot: slot })) {
          setMessage("Recorded: the participant prefers " + slotLabel(slot), "info");
        }
      });
    }
    $("blind").addEventListener("click", () => {
      const blind = !S.ab.blind;
      if (send({ type: "ab_blind", blind: blind })) setAB({ blind: blind });
    });
    const dialog = $("choose-dialog");
    $("choose").addEventListener("click", () => {
      if (typeof dialog.showModal === "function") dialog.showModal();
      else if (window.confirm("Record the set in force as the participant's final choice?")) choose();
    });
    $("choose-confirm").addEventListener("click", () => {
      dialog.close();
      choose();
    });
    $("choose-cancel").addEventListener("click", () => dialog.close());
    $("jnd-param").addEventListener("change", showJndUnit);
    $("jnd-start").addEventListener("click", startJnd);
    $("jnd-stop").addEventListener("click", () => send({ type: "jnd_stop" }));
    $("jnd-close").addEventListener("click", () => {
      S.jnd = null;
      document.body.classList.remove("jnd-blind");
      renderJnd();
    });
    for (const k of [1, 2]) $("jnd-answer-" + k).addEventListener("click", () => answerJnd(k));
    $("participant").addEventListener("change", () => {
      const id = $("participant").value.trim();
      $("participant").value = id;
      if (!id) {
        setMessage("A participant id cannot be empty: type one, e.g. P07", "error");
        return;
      }
      if (send({ type: "participant", id: id })) {
        S.participant = id;
        setMessage("Participant " + id, "info");
      }
    });
    $("participant").addEventListener("keydown", (e) => {
      if (e.key === "Enter") $("participant").blur();
    });
    $("zoom-latch").addEventListener("click", () => {
      S.zoomLatch = !S.zoomLatch;
      $("zoom-latch").setAttribute("aria-pressed", S.zoomLatch ? "true" : "false");
      invalidate();
    });
    $("mute").addEventListener("click", () => {
      const btn = $("mute");
      if (sound.on) sound.disable();
      else sound.enable();
      btn.textContent = sound.on ? "Mute" : "Sound on";
      btn.classList.toggle("on", sound.on);
      btn.setAttribute("aria-label", sound.on ? "Mute the sound" : "Turn the sound on");
    });
    if (window.ResizeObserver) {
      const ro = new ResizeObserver(() => {
        invalidate();
      });
      for (const id of ["door", "force-angle", "strip"]) ro.observe($(id).parentElement);
    } else {
      window.addEventListener("resize", () => {
        invalidate();
      });
    }
  }

  function choose() {
    if (send({ type: "choose" })) setMessage("Final choice sent", "info");
  }

  S.send = send;
  S.handle = handle;
  wire();
  setConnected(false);
  setAB(S.ab);
  loadDeclaration();
  connect();
  setInterval(slowTimer, HEALTH_MS);
  invalidate();
})();
