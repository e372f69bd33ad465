// hydroarm view --out: the chart panel of the recording (hydroarm.studies.viewer.write_html).
// The time cursor of every chart follows viser's playback bar: its slider's aria-valuenow is
// the recording's time (s from the run's first sample), read once a frame. The joint selector
// shows that joint's charts.
(function () {
  "use strict";
  const panel = document.getElementById("hydroarm-panel");
  const start = Number(panel.dataset.start);
  const span = Number(panel.dataset.span);
  const plotWidth = Number(panel.dataset.plotWidth);
  const clock = document.getElementById("hydroarm-clock");
  let shown = NaN;
  function follow() {
    const slider = document.querySelector('#root [role="slider"][aria-valuenow]');
    const time = slider === null ? NaN : Number(slider.getAttribute("aria-valuenow"));
    if (Number.isFinite(time) && time !== shown) {
      shown = time;
      const offset = Math.min(Math.max(time / span, 0), 1) * plotWidth;
      document.documentElement.style.setProperty("--hydroarm-cursor-x", offset.toFixed(2) + "px");
      clock.textContent = "t = " + (start + time).toFixed(2) + " s";
    }
    window.requestAnimationFrame(follow);
  }
  window.requestAnimationFrame(follow);
  const joint = document.getElementById("hydroarm-joint");
  joint.addEventListener("change", function () {
    for (const group of panel.querySelectorAll("[data-joint]")) {
      group.hidden = group.dataset.joint !== joint.value;
    }
  });
})();
