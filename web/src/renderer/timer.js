/**
 * Frame time: GPU time from EXT_disjoint_timer_query_webgl2 when the device has it (results arrive a few
 * frames later), otherwise wall-clock time around the draw calls plus gl.finish().
 */
export class FrameTimer {
  constructor(gl) {
    this.gl = gl;
    this.ext = gl.getExtension('EXT_disjoint_timer_query_webgl2');
    this.pending = [];
    this.lastMs = null;
    this.source = this.ext ? 'GPU timer query' : 'wall clock';
    this.t0 = 0;
  }

  begin() {
    if (this.ext) {
      if (this.pending.length > 4) return;  // do not pile up queries on a slow device
      const q = this.gl.createQuery();
      this.gl.beginQuery(this.ext.TIME_ELAPSED_EXT, q);
      this.active = q;
    } else {
      this.t0 = performance.now();
    }
  }

  end() {
    const gl = this.gl;
    if (this.ext) {
      if (!this.active) return;
      gl.endQuery(this.ext.TIME_ELAPSED_EXT);
      this.pending.push(this.active);
      this.active = null;
    } else {
      gl.finish();
      this.lastMs = performance.now() - this.t0;
    }
  }

  /** Collect finished queries; returns the latest time in ms (or null). */
  poll() {
    if (!this.ext) return this.lastMs;
    const gl = this.gl;
    const disjoint = gl.getParameter(this.ext.GPU_DISJOINT_EXT);
    while (this.pending.length) {
      const q = this.pending[0];
      if (!gl.getQueryParameter(q, gl.QUERY_RESULT_AVAILABLE)) break;
      const ns = gl.getQueryParameter(q, gl.QUERY_RESULT);
      gl.deleteQuery(q);
      this.pending.shift();
      if (!disjoint) this.lastMs = ns / 1e6;
    }
    return this.lastMs;
  }
}
