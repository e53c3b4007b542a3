import { defineConfig } from 'vite';
import { fileURLToPath } from 'node:url';

// The viewer is served by the Kiln server at / (and /app/): relative asset URLs work under both.
// Shaders are read from ../proto/glsl (one source with the Python renderer), bundled as text.
// Two pages: the viewer (index.html) and the @kiln/three example (kiln-three/example/index.html -> dist/kiln-three/example/).
export default defineConfig({
  base: './',
  build: {
    rollupOptions: {
      input: {
        main: fileURLToPath(new URL('index.html', import.meta.url)),
        'kiln-three': fileURLToPath(new URL('kiln-three/example/index.html', import.meta.url)),
      },
    },
    outDir: 'dist',
    emptyOutDir: true,
    chunkSizeWarningLimit: 1500,
    sourcemap: false,
  },
  server: {
    fs: { allow: [fileURLToPath(new URL('..', import.meta.url))] },
    proxy: { '/v1': 'http://127.0.0.1:8000', '/healthz': 'http://127.0.0.1:8000' },
  },
  test: {
    include: ['tests/**/*.test.js'],
    environment: 'node',
  },
});
