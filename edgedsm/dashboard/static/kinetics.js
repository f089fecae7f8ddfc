// The kinetics curve (docs/kinetics.md, issue 37): a region's decorrelation time τ (s) or its
// speckle rate 1/τ (Hz) against time on a log axis (a drying film spans decades), the device's
// drying stages ([[kinetics.stages]]) as horizontal lines, the stages reached (the daemon's `stage`
// alerts) as vertical marks. A reading without a number is never drawn as one: it is a gap in the
// curve with its status written in it (dark, saturated, not speckle, warming up), and above/below
// is a triangle at its bound pointing to where τ lies. Strings reach the page through fillText only.
"use strict";

const edgedsmKinetics = (() => {
  const STAGE = "#8e44ad"; // stage thresholds: dashed purple lines
  const MARK = "#c0392b"; // stages reached: solid red vertical lines
  const GAP = "rgba(154, 160, 173, 0.25)";
  const HEIGHT = 240;
  let plot = null;
  let view = "tau";
  let data = { readings: [], stages: [], alerts: [], region: null };
  // what the last draw put on the canvas (canvas pixels), for the browser tests and the curious
  let drawn = { lines: [], marks: [], gaps: [], bounds: [] };

  const usable = (v) => typeof v === "number" && isFinite(v) && v > 0;
  const shown = (seconds) => (view === "tau" ? seconds : 1 / seconds); // τ in s, or the rate in Hz
  const stageValue = (stage) => (view === "tau" ? 1 / stage.rate_below_hz : stage.rate_below_hz);
  const unit = () => (view === "tau" ? "s" : "Hz");

  function stageName(alert) {
    // the daemon's reason: "drying stage tack_free reached: speckle rate ..."
    const found = /drying stage (\S+) reached/.exec(typeof alert.reason === "string" ? alert.reason : "");
    return found ? found[1] : "stage";
  }

  function stageAlerts() {
    return data.alerts.filter((a) => a && a.type === "stage" && a.region === data.region && typeof a.t === "number");
  }

  function series() {
    const xs = data.readings.map((r) => r[0]);
    const ys = data.readings.map((r) => (r[2] === "ok" && usable(r[1]) ? shown(r[1]) : null));
    return [xs, ys];
  }

  function range(u, min, max) {
    // whole decades around the curve, the bounds and the stage lines
    const values = [min, max, ...data.stages.map(stageValue),
      ...data.readings.filter((r) => usable(r[3])).map((r) => shown(r[3]))].filter(usable);
    if (!values.length) return [0.01, 100];
    const lo = Math.floor(Math.log10(Math.min(...values)));
    const hi = Math.ceil(Math.log10(Math.max(...values)));
    return [10 ** lo, 10 ** Math.max(hi, lo + 1)];
  }

  function runs() {
    // consecutive readings without a number and of one status: [status, from t, to t, readings]
    const out = [];
    data.readings.forEach((r, i) => {
      if (r[2] === "ok" && usable(r[1])) return;
      const next = data.readings[i + 1];
      const end = next ? next[0] : r[0];
      const last = out[out.length - 1];
      if (last && last.status === r[2] && last.index === i - 1) { last.to = end; last.index = i; last.readings.push(r); } else {
        out.push({ status: String(r[2]), from: r[0], to: end, index: i, readings: [r] });
      }
    });
    return out;
  }

  function triangle(ctx, x, y, up, size) {
    ctx.beginPath();
    ctx.moveTo(x, y + (up ? -size : size));
    ctx.lineTo(x - size, y + (up ? size : -size) / 2);
    ctx.lineTo(x + size, y + (up ? size : -size) / 2);
    ctx.closePath();
    ctx.fill();
  }

  function draw(u) {
    const ctx = u.ctx;
    const { left, top, width, height } = u.bbox;
    const inside = (x) => x >= left - 1 && x <= left + width + 1;
    const px = devicePixelRatio;
    drawn = { lines: [], marks: [], gaps: [], bounds: [] };
    ctx.save();
    ctx.font = `${12 * px}px system-ui, sans-serif`;
    // statuses without a number: a grey band with the status in it (labels of runs too close
    // for their text stacked), bounds as triangles
    let labelEnd = -Infinity, row = 0;
    for (const run of runs()) {
      const x0 = Math.max(left, u.valToPos(run.from, "x", true));
      const x1 = Math.min(left + width, u.valToPos(run.to, "x", true));
      if (x1 < left || x0 > left + width) continue;
      const label = run.status.replace("_", " ");
      ctx.fillStyle = GAP;
      ctx.fillRect(x0, top, Math.max(x1 - x0, 2 * px), height);
      ctx.fillStyle = "#4b5563";
      ctx.textAlign = "left"; ctx.textBaseline = "top";
      row = x0 < labelEnd ? Math.min(row + 1, 3) : 0;
      ctx.fillText(label, x0 + 3 * px, top + (3 + 14 * row) * px);
      const end = x0 + 7 * px + ctx.measureText(label).width;
      labelEnd = row === 0 ? end : Math.max(labelEnd, end);
      drawn.gaps.push({ status: run.status, from: run.from, to: run.to, x0, x1 });
      if (run.status !== "above" && run.status !== "below") continue;
      ctx.fillStyle = "#374151";
      for (const [t, , status, bound] of run.readings) {
        if (!usable(bound)) continue;
        const x = u.valToPos(t, "x", true), y = u.valToPos(shown(bound), "y", true);
        if (!inside(x) || y < top || y > top + height) continue;
        // above: τ is longer than the bound (up on τ, down on the rate); below the other way
        triangle(ctx, x, y, (status === "above") === (view === "tau"), 4 * px);
        drawn.bounds.push({ t, status, value: shown(bound), x, y });
      }
    }
    // the stage thresholds, named at the right end
    ctx.lineWidth = 1.5 * px;
    for (const stage of data.stages) {
      const value = stageValue(stage);
      const y = u.valToPos(value, "y", true);
      if (!(y >= top && y <= top + height)) continue;
      ctx.strokeStyle = STAGE; ctx.setLineDash([6 * px, 4 * px]);
      ctx.beginPath(); ctx.moveTo(left, y); ctx.lineTo(left + width, y); ctx.stroke();
      ctx.fillStyle = STAGE; ctx.textAlign = "right"; ctx.textBaseline = "bottom";
      ctx.fillText(`${stage.name} ${fmt(value, 3)} ${unit()}`, left + width - 3 * px, y - 2 * px);
      drawn.lines.push({ name: stage.name, value, y });
    }
    // the stages reached: where the daemon's alert says
    ctx.setLineDash([]);
    for (const alert of stageAlerts()) {
      const x = u.valToPos(alert.t, "x", true);
      if (!inside(x)) continue;
      ctx.strokeStyle = MARK;
      ctx.beginPath(); ctx.moveTo(x, top); ctx.lineTo(x, top + height); ctx.stroke();
      ctx.fillStyle = MARK; ctx.textAlign = "left"; ctx.textBaseline = "top";
      ctx.fillText(stageName(alert), x + 3 * px, top + 18 * px);
      drawn.marks.push({ name: stageName(alert), t: alert.t, x });
    }
    ctx.restore();
  }

  function caption() {
    const what = view === "tau" ? "decorrelation time τ (s)" : "speckle rate 1/τ (Hz)";
    const stages = data.stages.length ? `, the drying stages (dashed) and when each was reached (red)` : "";
    $("kinetics-caption").textContent = `${what} on a log axis${stages}; grey: no number (the status says why)`;
  }

  function render() {
    const box = $("kinetics-box");
    box.hidden = !(data.readings.length || data.stages.length);
    if (box.hidden) return;
    caption();
    const width = plotWidth();
    if (!plot) {
      plot = new uPlot({
        width, height: HEIGHT,
        scales: { x: { time: true }, y: { distr: 3, log: 10, range } },
        series: [{}, { label: "kinetics", stroke: "#3060d0", width: 2, points: { show: false } }],
        axes: [{}, { label: unit(), size: 60 }],
        hooks: { draw: [draw] },
      }, series(), $("kinetics-plot"));
    } else {
      plot.setData(series());
      if (Math.abs(plot.width - width) > 8) plot.setSize({ width, height: HEIGHT });
    }
  }

  return {
    show(history) {
      data = { readings: history.kinetics || [], stages: history.stages || [], alerts: history.alerts || [],
        region: history.region };
      render();
    },
    append(t, reading) {
      // a statistics message's reading (the stats carry tau_s, status, bound_s)
      if (!reading || typeof reading.status !== "string") return;
      const last = data.readings.length ? data.readings[data.readings.length - 1][0] : -Infinity;
      if (!(t > last)) return;
      data.readings.push([t, usable(reading.tau_s) ? reading.tau_s : null, reading.status,
        usable(reading.bound_s) ? reading.bound_s : null]);
      render();
    },
    redraw() { if (plot) plot.redraw(); },
    resize() { if (plot) plot.setSize({ width: plotWidth(), height: HEIGHT }); },
    setView(name) { view = name === "rate" ? "rate" : "tau"; if (plot) { plot.destroy(); plot = null; } render(); },
    // read-only views of what is drawn (the browser tests)
    state: () => ({
      view, distr: plot ? plot.scales.y.distr : null, drawn,
      points: plot ? plot.data[0].map((t, i) => [t, plot.data[1][i]]) : [],
      canvas: plot ? plot.ctx.canvas.getBoundingClientRect().toJSON() : null,
      ratio: devicePixelRatio,
    }),
    pos: (values) => (plot ? values.map((v) => plot.valToPos(v, "y", true)) : []),
  };
})();
