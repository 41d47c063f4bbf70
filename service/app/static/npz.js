// Reads the NPZ files the trajectory route streams: a zip (ZIP64 aware, stored, not
// compressed) of .npy arrays. readNpz(ArrayBuffer) -> {name: {shape, data}}, data a
// Float64Array (8-byte integers are converted to numbers).
"use strict";

function readNpz(buffer) {
  const view = new DataView(buffer);
  const u64 = (o) => Number(view.getBigUint64(o, true));
  let eocd = -1;
  for (let o = buffer.byteLength - 22; o >= Math.max(0, buffer.byteLength - 65557); o--) {
    if (view.getUint32(o, true) === 0x06054b50) { eocd = o; break; }
  }
  if (eocd < 0) throw new Error("not a zip file");
  let entries = view.getUint16(eocd + 10, true);
  let cdOffset = view.getUint32(eocd + 16, true);
  if (entries === 0xffff || cdOffset === 0xffffffff) {
    const loc = eocd - 20;
    if (view.getUint32(loc, true) !== 0x07064b50) throw new Error("bad zip64 locator");
    const z = u64(loc + 8);
    entries = u64(z + 32);
    cdOffset = u64(z + 48);
  }
  const out = {};
  let p = cdOffset;
  for (let i = 0; i < entries; i++) {
    if (view.getUint32(p, true) !== 0x02014b50) throw new Error("bad zip directory");
    let size = view.getUint32(p + 20, true);
    let usize = view.getUint32(p + 24, true);
    const nameLen = view.getUint16(p + 28, true);
    const extraLen = view.getUint16(p + 30, true);
    const commentLen = view.getUint16(p + 32, true);
    let local = view.getUint32(p + 42, true);
    const name = new TextDecoder().decode(new Uint8Array(buffer, p + 46, nameLen));
    let e = p + 46 + nameLen;
    const end = e + extraLen;
    while (e < end) {  // the ZIP64 extra field holds the sizes that did not fit
      const id = view.getUint16(e, true), len = view.getUint16(e + 2, true);
      if (id === 1) {
        let q = e + 4;
        if (usize === 0xffffffff) { usize = u64(q); q += 8; }
        if (size === 0xffffffff) { size = u64(q); q += 8; }
        if (local === 0xffffffff) { local = u64(q); q += 8; }
      }
      e += 4 + len;
    }
    const data = local + 30 + view.getUint16(local + 26, true) + view.getUint16(local + 28, true);
    out[name.replace(/\.npy$/, "")] = readNpy(buffer, data, size);
    p = end + commentLen;
  }
  return out;
}

function readNpy(buffer, offset, size) {
  const view = new DataView(buffer, offset, size);
  const major = view.getUint8(6);
  const headerLen = major === 1 ? view.getUint16(8, true) : view.getUint32(8, true);
  const start = major === 1 ? 10 : 12;
  const header = new TextDecoder().decode(new Uint8Array(buffer, offset + start, headerLen));
  const descr = /'descr':\s*'([^']+)'/.exec(header)[1];
  const shape = /'shape':\s*\(([^)]*)\)/.exec(header)[1].split(",")
    .map((s) => s.trim()).filter((s) => s).map(Number);
  const count = shape.reduce((a, b) => a * b, 1);
  const body = buffer.slice(offset + start + headerLen, offset + start + headerLen + count * 8);
  let data;
  if (descr === "<f8") data = new Float64Array(body);
  else if (descr === "<i8") data = Float64Array.from(new BigInt64Array(body), Number);
  else if (descr === "<f4") data = Float64Array.from(new Float32Array(body.slice(0, count * 4)));
  // H5MD's periodic `image` (int32), served beside the positions.
  else if (descr === "<i4") data = Float64Array.from(new Int32Array(body.slice(0, count * 4)));
  else throw new Error("unsupported array type " + descr);
  return { shape, data };
}
