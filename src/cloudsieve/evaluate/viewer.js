/* cloudsieve report viewer: point clouds in <canvas> elements, WebGL (a 2D-canvas fallback without it).
 *
 * Reads the JSON in <script type="application/json" id="cloudsieve-data">:
 *   {"clouds": [{"n": N, "xyz": base64 of uint16 (3N, little-endian, 0..65535 across "bounds")}],
 *    "bounds": [[xmin, ymin, zmin], [xmax, ymax, zmax]],
 *    "values": [base64 of uint8 (N), ...],
 *    "views": [{"canvas": id, "cloud": i, "values": j or null, "colour": [r, g, b] (0..1)}]}
 * A view coloured by values maps 0 -> red and 255 -> blue (matplotlib's jet reversed, as errors.ply).
 * Every view shares one camera: drag rotates, the wheel zooms, shift-drag or right-drag pans,
 * a double click resets. No network access, no dependency.
 * Status for tests: document.body.dataset.rendered = "webgl" | "2d" once every view is drawn;
 * document.body.dataset.renderMs: milliseconds from navigation to the first frame; document.body.dataset.errors counts uncaught errors.
 */
(function () {
  "use strict";
  window.addEventListener("error", function () {
    document.body.dataset.errors = String(Number(document.body.dataset.errors || 0) + 1);
  });

  function decode(b64, Type) {
    var s = atob(b64), bytes = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) bytes[i] = s.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  function jet(t) { // matplotlib's jet at 1 - t: 0 red, 1 blue
    var x = 1 - t;
    function c(v) { return Math.max(0, Math.min(1, v)); }
    return [c(1.5 - Math.abs(4 * x - 3)), c(1.5 - Math.abs(4 * x - 2)), c(1.5 - Math.abs(4 * x - 1))];
  }

  // ---- 4x4 column-major matrices
  function mul(a, b) {
    var o = new Float32Array(16);
    for (var i = 0; i < 4; i++) for (var j = 0; j < 4; j++) {
      var s = 0;
      for (var k = 0; k < 4; k++) s += a[k * 4 + j] * b[i * 4 + k];
      o[i * 4 + j] = s;
    }
    return o;
  }
  function perspective(fovy, aspect, near, far) {
    var f = 1 / Math.tan(fovy / 2), o = new Float32Array(16);
    o[0] = f / aspect; o[5] = f; o[10] = (far + near) / (near - far); o[11] = -1;
    o[14] = 2 * far * near / (near - far);
    return o;
  }
  function camera_matrix(cam, ext) { // model (unit cube scaled by ext, centred) -> view
    var cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw), cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch);
    var m = new Float32Array(16); // scale to extents, centre
    m[0] = ext[0]; m[5] = ext[1]; m[10] = ext[2]; m[15] = 1;
    m[12] = -ext[0] / 2; m[13] = -ext[1] / 2; m[14] = -ext[2] / 2;
    var rz = new Float32Array([cy, sy, 0, 0, -sy, cy, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]); // yaw about z (up)
    var rx = new Float32Array([1, 0, 0, 0, 0, cp, sp, 0, 0, -sp, cp, 0, 0, 0, 0, 1]); // pitch
    var t = new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, cam.panx, cam.pany, -cam.dist, 1]);
    return mul(t, mul(rx, mul(rz, m)));
  }

  var VS = "attribute vec3 pos; attribute float val; uniform mat4 mvp; uniform float size; uniform float useval;" +
    "uniform vec3 colour; varying vec3 col;" +
    "vec3 jet(float t){float x=1.0-t;return clamp(vec3(1.5-abs(4.0*x-3.0),1.5-abs(4.0*x-2.0),1.5-abs(4.0*x-1.0)),0.0,1.0);}" +
    "void main(){gl_Position=mvp*vec4(pos,1.0);gl_PointSize=size;col=useval>0.5?jet(val):colour;}";
  var FS = "precision mediump float; varying vec3 col; void main(){gl_FragColor=vec4(col,1.0);}";

  function glView(canvas, xyz, vals, colour) {
    var gl = canvas.getContext("webgl", {antialias: false, preserveDrawingBuffer: true});
    if (!gl) return null;
    function shader(type, src) {
      var s = gl.createShader(type);
      gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      return s;
    }
    var prog = gl.createProgram();
    gl.attachShader(prog, shader(gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
    gl.useProgram(prog);
    var pb = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, pb); gl.bufferData(gl.ARRAY_BUFFER, xyz, gl.STATIC_DRAW);
    var lp = gl.getAttribLocation(prog, "pos");
    gl.enableVertexAttribArray(lp); gl.vertexAttribPointer(lp, 3, gl.UNSIGNED_SHORT, true, 0, 0);
    var lv = gl.getAttribLocation(prog, "val");
    if (vals) {
      var vb = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, vb); gl.bufferData(gl.ARRAY_BUFFER, vals, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(lv); gl.vertexAttribPointer(lv, 1, gl.UNSIGNED_BYTE, true, 0, 0);
    } else {
      gl.disableVertexAttribArray(lv); gl.vertexAttrib1f(lv, 0);
    }
    gl.uniform1f(gl.getUniformLocation(prog, "useval"), vals ? 1 : 0);
    gl.uniform3fv(gl.getUniformLocation(prog, "colour"), colour);
    gl.enable(gl.DEPTH_TEST);
    var n = xyz.length / 3;
    return function (mvp, size) {
      gl.viewport(0, 0, canvas.width, canvas.height);
      gl.clearColor(1, 1, 1, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.uniformMatrix4fv(gl.getUniformLocation(prog, "mvp"), false, mvp);
      gl.uniform1f(gl.getUniformLocation(prog, "size"), size);
      gl.drawArrays(gl.POINTS, 0, n);
    };
  }

  function canvasView(canvas, xyz, vals, colour) { // no WebGL: project in JS, z-buffer, one pixel a point
    var ctx = canvas.getContext("2d"), n = xyz.length / 3, lut = [];
    for (var i = 0; i < 256; i++) lut.push(jet(i / 255));
    return function (mvp) {
      var w = canvas.width, h = canvas.height, img = ctx.createImageData(w, h), d = img.data;
      var zb = new Float32Array(w * h).fill(Infinity);
      for (var p = 0; p < d.length; p++) d[p] = 255;
      for (var k = 0; k < n; k++) {
        var x = xyz[3 * k] / 65535, y = xyz[3 * k + 1] / 65535, z = xyz[3 * k + 2] / 65535;
        var cw = mvp[3] * x + mvp[7] * y + mvp[11] * z + mvp[15];
        if (cw <= 0) continue;
        var cx = (mvp[0] * x + mvp[4] * y + mvp[8] * z + mvp[12]) / cw;
        var cy = (mvp[1] * x + mvp[5] * y + mvp[9] * z + mvp[13]) / cw;
        var cz = (mvp[2] * x + mvp[6] * y + mvp[10] * z + mvp[14]) / cw;
        var px = Math.floor((cx + 1) * w / 2), py = Math.floor((1 - cy) * h / 2);
        if (px < 0 || py < 0 || px >= w || py >= h || cz >= zb[py * w + px]) continue;
        zb[py * w + px] = cz;
        var c = vals ? lut[vals[k]] : colour, o = 4 * (py * w + px);
        d[o] = 255 * c[0]; d[o + 1] = 255 * c[1]; d[o + 2] = 255 * c[2];
      }
      ctx.putImageData(img, 0, 0);
    };
  }

  function start() {
    var el = document.getElementById("cloudsieve-data");
    if (!el) return;
    var data = JSON.parse(el.textContent), lo = data.bounds[0], hi = data.bounds[1];
    var span = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
    var ext = [(hi[0] - lo[0]) / span, (hi[1] - lo[1]) / span, (hi[2] - lo[2]) / span];
    var clouds = data.clouds.map(function (c) { return decode(c.xyz, Uint16Array); });
    var values = (data.values || []).map(function (v) { return decode(v, Uint8Array); });
    var home = {yaw: -0.6, pitch: -1.0, dist: 1.7, panx: 0, pany: 0};
    var cam = Object.assign({}, home), views = [], kind = "webgl";
    data.views.forEach(function (v) {
      var canvas = document.getElementById(v.canvas);
      var ratio = window.devicePixelRatio || 1;
      canvas.width = Math.round(canvas.clientWidth * ratio) || 480;
      canvas.height = Math.round(canvas.clientHeight * ratio) || 360;
      var vals = v.values === null || v.values === undefined ? null : values[v.values];
      var draw = glView(canvas, clouds[v.cloud], vals, v.colour || [0.2, 0.2, 0.2]);
      if (!draw) { draw = canvasView(canvas, clouds[v.cloud], vals, v.colour || [0.2, 0.2, 0.2]); kind = "2d"; }
      views.push({canvas: canvas, draw: draw});
      attach(canvas);
    });
    var pending = false;
    function redraw() {
      pending = false;
      views.forEach(function (v) {
        var aspect = v.canvas.width / v.canvas.height;
        var mvp = mul(perspective(0.8, aspect, 0.01, 100), camera_matrix(cam, ext));
        v.draw(mvp, Math.max(1, Math.round(2 * (window.devicePixelRatio || 1))));
      });
    }
    function schedule() { if (!pending) { pending = true; requestAnimationFrame(redraw); } }
    function attach(canvas) {
      var drag = null;
      canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
      canvas.addEventListener("mousedown", function (e) { drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2}; });
      window.addEventListener("mouseup", function () { drag = null; });
      window.addEventListener("mousemove", function (e) {
        if (!drag) return;
        var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
        drag.x = e.clientX; drag.y = e.clientY;
        if (drag.pan) { cam.panx += dx * cam.dist / 600; cam.pany -= dy * cam.dist / 600; }
        else { cam.yaw += dx * 0.01; cam.pitch = Math.max(-3.1, Math.min(0, cam.pitch + dy * 0.01)); }
        schedule();
      });
      canvas.addEventListener("wheel", function (e) {
        e.preventDefault();
        cam.dist = Math.max(0.05, Math.min(20, cam.dist * Math.exp(e.deltaY * 0.001)));
        schedule();
      }, {passive: false});
      canvas.addEventListener("dblclick", function () { cam = Object.assign({}, home); schedule(); });
    }
    redraw();
    document.body.dataset.rendered = kind;
    document.body.dataset.renderMs = String(Math.round(performance.now()));
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
