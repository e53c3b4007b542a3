/**
 * Plain application state with change notification (glTF-Sample-Viewer keeps state apart from the code
 * that renders it). No DOM, no GL: UI modules subscribe, the renderer reads.
 */
export function createStore(initial) {
  let state = { ...initial };
  const listeners = new Set();
  return {
    get: () => state,
    set(patch) {
      const prev = state;
      state = { ...state, ...(typeof patch === 'function' ? patch(state) : patch) };
      for (const l of listeners) l(state, prev);
    },
    subscribe(fn) { listeners.add(fn); return () => listeners.delete(fn); },
  };
}

/** The app's initial state. */
export const INITIAL_STATE = {
  route: { page: 'bake', params: {} },   // bake | viewer | dashboard
  scenes: [],                            // GET /v1/scenes items
  currentSceneId: null,
  bakes: {},                             // id -> latest bake object (GET /v1/bakes/{id} or SSE snapshot merged)
  currentBakeId: null,
  viewer: {
    mode: 'direct',                      // a GI mode id (modes.js)
    camera: 'orbit',                     // orbit | fly
    probes: false,                       // show probe spheres
    probeColoring: 'state',              // state | sh
    exposure: 1.0,
    output: 'shaded',                    // shaded | indirect | direct | albedo
  },
  compare: [],                           // up to two bake ids picked on the dashboard
};
