// Reads members of a NumPy .npz (a zip of .npy files) in the browser, so the viewer takes
// per-face arrays straight from faces.npz. Stored or deflated members (what numpy and
// planner/outputs/report.py write); decompression by the browser's DecompressionStream.

const TYPED = {
  '|b1': Uint8Array, '|u1': Uint8Array, '|i1': Int8Array, '<u2': Uint16Array,
  '<i2': Int16Array, '<u4': Uint32Array, '<i4': Int32Array, '<f4': Float32Array,
  '<f8': Float64Array, '<i8': BigInt64Array, '<u8': BigUint64Array,
};

// name -> {method, offset, size} of every member, from the zip's central directory
function members(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let end = -1;
  for (let i = bytes.length - 22; i >= Math.max(0, bytes.length - 22 - 65535); i -= 1) {
    if (view.getUint32(i, true) === 0x06054b50) { end = i; break; }
  }
  if (end < 0) throw new Error('not a zip archive (no end of central directory)');
  const count = view.getUint16(end + 10, true);
  let at = view.getUint32(end + 16, true);
  if (at === 0xffffffff) throw new Error('zip64 archives are not read here');
  const out = new Map();
  const decoder = new TextDecoder();
  for (let k = 0; k < count; k += 1) {
    if (view.getUint32(at, true) !== 0x02014b50) throw new Error('broken zip central directory');
    const method = view.getUint16(at + 10, true);
    const size = view.getUint32(at + 20, true);
    const nameLength = view.getUint16(at + 28, true);
    const extraLength = view.getUint16(at + 30, true);
    const commentLength = view.getUint16(at + 32, true);
    const local = view.getUint32(at + 42, true);
    const name = decoder.decode(bytes.subarray(at + 46, at + 46 + nameLength));
    // the data follows the local header, whose name and extra fields may differ in length
    const offset = local + 30 + view.getUint16(local + 26, true) + view.getUint16(local + 28, true);
    out.set(name, { method, offset, size });
    at += 46 + nameLength + extraLength + commentLength;
  }
  return out;
}

async function inflate(data) {
  const stream = new Blob([data]).stream().pipeThrough(new DecompressionStream('deflate-raw'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// a one-dimensional .npy array as a typed array
function parseNpy(bytes, name) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes[0] !== 0x93 || String.fromCharCode(...bytes.subarray(1, 6)) !== 'NUMPY') {
    throw new Error(`${name} is not a .npy array`);
  }
  const major = bytes[6];
  const headerLength = major === 1 ? view.getUint16(8, true) : view.getUint32(8, true);
  const start = major === 1 ? 10 : 12;
  const header = new TextDecoder().decode(bytes.subarray(start, start + headerLength));
  const descr = (header.match(/'descr':\s*'([^']+)'/) || [])[1];
  const shape = (header.match(/'shape':\s*\(([^)]*)\)/) || [])[1];
  const Typed = TYPED[descr];
  if (!Typed) throw new Error(`${name}: dtype ${descr} is not read here`);
  if (/'fortran_order':\s*True/.test(header)) throw new Error(`${name}: Fortran order`);
  const dims = String(shape || '').split(',').map((s) => s.trim()).filter(Boolean).map(Number);
  const length = dims.reduce((a, b) => a * b, 1);
  const data = bytes.slice(start + headerLength, start + headerLength + length * Typed.BYTES_PER_ELEMENT);
  return new Typed(data.buffer, 0, length);
}

// {name: typed array} of the wanted members (names without ".npy"); missing ones are left out
export async function readNpz(buffer, wanted) {
  const bytes = new Uint8Array(buffer);
  const index = members(bytes);
  const out = {};
  for (const name of wanted) {
    const entry = index.get(`${name}.npy`);
    if (!entry) continue;
    const raw = bytes.subarray(entry.offset, entry.offset + entry.size);
    let data;
    if (entry.method === 0) data = raw;
    else if (entry.method === 8) data = await inflate(raw);
    else throw new Error(`${name}.npy: zip method ${entry.method} is not read here`);
    out[name] = parseNpy(data, `${name}.npy`);
  }
  return out;
}
