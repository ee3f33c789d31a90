#!/usr/bin/env node
// Writes the Stanford bunny from the npm package `bunny` ({positions, cells}) as a binary little-endian PLY.
// Usage: node tools/scripts/bunny-to-ply.js OUT_DIR   -> prints OUT_DIR/bunny.ply
'use strict';
const fs = require('fs');
const path = require('path');

const outDir = process.argv[2] || path.join('build', 'data');
const outFile = path.join(outDir, 'bunny.ply');
if (fs.existsSync(outFile)) {
  console.log(outFile);
  process.exit(0);
}

const bunny = require('bunny');
const { positions, cells } = bunny;
if (!Array.isArray(positions) || !Array.isArray(cells) || positions.length === 0 || cells.length === 0) {
  console.error('bunny-to-ply: the bunny package has no positions or cells');
  process.exit(1);
}

const header =
  'ply\n' +
  'format binary_little_endian 1.0\n' +
  'comment Stanford bunny from the npm package bunny\n' +
  `element vertex ${positions.length}\n` +
  'property float x\nproperty float y\nproperty float z\n' +
  `element face ${cells.length}\n` +
  'property list uchar int vertex_indices\n' +
  'end_header\n';

const vertexBytes = positions.length * 12;
const faceBytes = cells.reduce((n, c) => n + 1 + 4 * c.length, 0);
const body = Buffer.alloc(vertexBytes + faceBytes);
let o = 0;
for (const p of positions) {
  for (let k = 0; k < 3; ++k) o = body.writeFloatLE(p[k], o);
}
for (const c of cells) {
  o = body.writeUInt8(c.length, o);
  for (const i of c) o = body.writeInt32LE(i, o);
}

// Write under a temporary name and rename, so an interrupted run never leaves a truncated file behind.
fs.mkdirSync(outDir, { recursive: true });
const tmp = `${outFile}.tmp${process.pid}`;
fs.writeFileSync(tmp, Buffer.concat([Buffer.from(header, 'ascii'), body]));
fs.renameSync(tmp, outFile);
console.log(outFile);
