// Point files as the page reads them before upload: the core's rule (read_points,
// core/include/spokemesh/io.hpp; README "Input"), so that a file the page accepts the
// CLI accepts and the other way round (tests/python/test_ui.py holds the two to it).
//   text  one point a line; numbers separated by blanks, commas or semicolons; `#`
//         starts a comment; blank lines skipped; a first line none of whose fields is a
//         number (a header) skipped
//   .npy  C-order (n, d) float64, float32, int64, int32 or int16, little-endian;
//         integers exact (|v| <= 2^53)
// Coordinates are finite, of magnitude at most 1e100. Each parser returns
// {n, d, values: Float64Array} or throws an Error naming the line (and column) or the
// element.
'use strict';

(() => {
  const MAX_COORDINATE = 1e100;
  // What C++'s std::from_chars reads as a double (the core's parser), with an optional
  // leading '+': decimal digits, a point, an exponent; inf and nan (then refused as
  // not finite).
  const NUMBER = /^[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan(?:\([0-9A-Za-z_]*\))?)$/i;
  const SEPARATORS = /[ \t,;\r\v\f]+/;

  function fields(line) { return line.split(SEPARATORS).filter(Boolean); }
  function isNumber(token) { return NUMBER.test(token) && !/^\+[+-]/.test(token); }
  function toNumber(token) {
    const t = token.replace(/^\+/, '').toLowerCase();
    if (t.startsWith('inf') || t.startsWith('-inf')) return t.startsWith('-') ? -Infinity : Infinity;
    if (t.startsWith('nan') || t.startsWith('-nan')) return NaN;
    return Number(t);
  }

  function parseText(text) {
    const rows = [];
    let d = 0;
    let first = true;
    const lines = text.split('\n');
    for (let i = 0; i < lines.length; ++i) {
      const hash = lines[i].indexOf('#');
      const line = hash >= 0 ? lines[i].slice(0, hash) : lines[i];
      const tokens = fields(line);
      if (!tokens.length) continue;
      const bad = tokens.findIndex((t) => !isNumber(t));
      if (bad >= 0) {
        if (first && tokens.every((t) => !isNumber(t))) {  // a header
          first = false;
          continue;
        }
        throw new Error('line ' + (i + 1) + ', column ' + (bad + 1) + ': cannot parse "' + tokens[bad].slice(0, 30) +
                        '" as a number');
      }
      first = false;
      const values = tokens.map(toNumber);
      if (d === 0) d = values.length;
      if (values.length !== d) {
        throw new Error('line ' + (i + 1) + ': ' + values.length + ' coordinates, but earlier lines have ' + d);
      }
      const wrong = values.findIndex((v) => !Number.isFinite(v) || Math.abs(v) > MAX_COORDINATE);
      if (wrong >= 0) {
        throw new Error('line ' + (i + 1) + ': coordinate ' + wrong + ' ' +
                        (Number.isFinite(values[wrong]) ? 'has magnitude above 1e100' : 'is not finite'));
      }
      rows.push(values);
    }
    if (!rows.length) throw new Error('no points (the input is empty)');
    const out = new Float64Array(rows.length * d);
    rows.forEach((r, i) => out.set(r, i * d));
    return { n: rows.length, d, values: out };
  }

  const KINDS = {
    f8: Float64Array, f4: Float32Array, i8: BigInt64Array, i4: Int32Array, i2: Int16Array,
  };

  function parseNpy(buffer) {
    const bytes = new Uint8Array(buffer);
    const magic = String.fromCharCode(...bytes.slice(1, 6));
    if (bytes.length < 10 || bytes[0] !== 0x93 || magic !== 'NUMPY') throw new Error('not a .npy file (no \\x93NUMPY magic)');
    const view = new DataView(buffer);
    const major = bytes[6];
    const headerLength = major === 1 ? view.getUint16(8, true) : view.getUint32(8, true);
    const start = major === 1 ? 10 : 12;
    const header = new TextDecoder().decode(bytes.slice(start, start + headerLength));
    const descr = /'descr':\s*'([^']+)'/.exec(header);
    const shape = /'shape':\s*\(([^)]*)\)/.exec(header);
    if (!descr || !shape) throw new Error('.npy header: no descr or shape in ' + header.slice(0, 80));
    const kind = /^[<=]([fi][248])$/.exec(descr[1]);
    const Kind = kind && KINDS[kind[1]];
    if (!Kind) {
      throw new Error('.npy dtype \'' + descr[1] + '\' is not supported (need float64, float32, int64, int32 or int16, ' +
                      'little-endian)');
    }
    if (/'fortran_order':\s*True/.test(header)) throw new Error('.npy array is in Fortran order (need C order)');
    const dims = shape[1].split(',').map((s) => s.trim()).filter(Boolean).map(Number);
    if (dims.length !== 2) throw new Error('.npy array must have shape (n, d), found ' + dims.length + ' axes');
    const [n, d] = dims;
    if (n === 0 || d === 0) throw new Error('no points (the input is empty)');
    const offset = start + headerLength;
    const need = n * d * Kind.BYTES_PER_ELEMENT;
    if (buffer.byteLength - offset < need) {
      throw new Error('truncated .npy data: expected ' + need + ' bytes, found ' + (buffer.byteLength - offset));
    }
    const raw = new Kind(buffer.slice(offset, offset + need));
    const values = new Float64Array(n * d);
    const limit = 2n ** 53n;
    for (let i = 0; i < values.length; ++i) {
      const where = 'element [' + Math.floor(i / d) + ', ' + (i % d) + ']';
      if (Kind === BigInt64Array) {
        if (raw[i] > limit || raw[i] < -limit) {
          throw new Error(where + ' = ' + raw[i] + ' is not exactly a double (integers are read up to 2^53 in magnitude)');
        }
        values[i] = Number(raw[i]);
        continue;
      }
      const v = Number(raw[i]);
      if (!Number.isFinite(v)) throw new Error(where + ' is not finite');
      if (Math.abs(v) > MAX_COORDINATE) throw new Error(where + ' has magnitude above 1e100');
      values[i] = v;
    }
    return { n, d, values };
  }

  window.spokemeshPointFiles = { parseText, parseNpy };
})();
