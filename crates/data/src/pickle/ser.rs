//! The pickler: protocol 4, numpy arrays in the `_reconstruct` + BUILD layout numpy itself
//! writes, so that `pickle.load` under numpy 1.x or 2.x rebuilds the same arrays.

use std::collections::HashMap;

use super::numpy::{encode_array, Encoded, Payload};
use super::objects::MAX_DEPTH;
use super::opcodes as op;
use super::{NdArray, PickleError, Value};

/// Items per APPENDS / SETITEMS / ADDITEMS batch, as CPython.
const BATCH: usize = 1000;

/// numpy 2 still provides `numpy.core.multiarray` (silently) for old pickles, numpy 1.x only
/// has this name: it loads everywhere.
const RECONSTRUCT: &str = "numpy.core.multiarray._reconstruct";

pub(crate) fn pickle(value: &Value) -> Result<Vec<u8>, PickleError> {
    let mut p = Pickler { out: vec![op::PROTO, 4], memo: HashMap::new() };
    p.value(value, 0)?;
    p.out.push(op::STOP);
    Ok(p.out)
}

struct Pickler {
    out: Vec<u8>,
    /// Memo slots of globals and dtypes, which every array repeats.
    memo: HashMap<String, u32>,
}

impl Pickler {
    fn op(&mut self, code: u8) {
        self.out.push(code);
    }

    /// Pushes memo slot `slot` (BINGET / LONG_BINGET).
    fn get(&mut self, slot: u32) {
        match u8::try_from(slot) {
            Ok(small) => self.out.extend([op::BINGET, small]),
            Err(_) => {
                self.op(op::LONG_BINGET);
                self.out.extend(slot.to_le_bytes());
            }
        }
    }

    /// Memoizes the top of the stack under `key`; slots are numbered like MEMOIZE reads them.
    fn memoize(&mut self, key: String) {
        self.op(op::MEMOIZE);
        let slot = self.memo.len() as u32;
        self.memo.insert(key, slot);
    }

    fn int(&mut self, v: i64) {
        if let Ok(b) = u8::try_from(v) {
            self.out.extend([op::BININT1, b]);
        } else if let Ok(w) = u16::try_from(v) {
            self.op(op::BININT2);
            self.out.extend(w.to_le_bytes());
        } else if let Ok(d) = i32::try_from(v) {
            self.op(op::BININT);
            self.out.extend(d.to_le_bytes());
        } else {
            // Minimal little-endian two's complement, like pickle.encode_long.
            let mut bytes = v.to_le_bytes().to_vec();
            while bytes.len() > 1 {
                let (last, prev) = (bytes[bytes.len() - 1], bytes[bytes.len() - 2]);
                if (last == 0 && prev & 0x80 == 0) || (last == 0xff && prev & 0x80 != 0) {
                    bytes.pop();
                } else {
                    break;
                }
            }
            self.out.extend([op::LONG1, bytes.len() as u8]);
            self.out.extend(bytes);
        }
    }

    fn str(&mut self, s: &str) {
        let n = s.len();
        if let Ok(n) = u8::try_from(n) {
            self.out.extend([op::SHORT_BINUNICODE, n]);
        } else if let Ok(n) = u32::try_from(n) {
            self.op(op::BINUNICODE);
            self.out.extend(n.to_le_bytes());
        } else {
            self.op(op::BINUNICODE8);
            self.out.extend((n as u64).to_le_bytes());
        }
        self.out.extend_from_slice(s.as_bytes());
    }

    fn bytes(&mut self, b: &[u8]) {
        let n = b.len();
        if let Ok(n) = u8::try_from(n) {
            self.out.extend([op::SHORT_BINBYTES, n]);
        } else if let Ok(n) = u32::try_from(n) {
            self.op(op::BINBYTES);
            self.out.extend(n.to_le_bytes());
        } else {
            self.op(op::BINBYTES8);
            self.out.extend((n as u64).to_le_bytes());
        }
        self.out.extend_from_slice(b);
    }

    fn global(&mut self, name: &str) -> Result<(), PickleError> {
        let (module, qualname) = name
            .rsplit_once('.')
            .filter(|(m, q)| !m.is_empty() && !q.is_empty())
            .ok_or_else(|| PickleError::Unpicklable(format!("global '{name}' is not 'module.name'")))?;
        let key = format!("global {name}");
        if let Some(&slot) = self.memo.get(&key) {
            self.get(slot);
            return Ok(());
        }
        self.str(module);
        self.str(qualname);
        self.op(op::STACK_GLOBAL);
        self.memoize(key);
        Ok(())
    }

    /// Writes `items` with `mark`-batched `many` opcodes (or `one` for a single item).
    fn batched<T>(
        &mut self,
        items: &[T],
        one: u8,
        many: u8,
        mut write: impl FnMut(&mut Self, &T) -> Result<(), PickleError>,
    ) -> Result<(), PickleError> {
        for chunk in items.chunks(BATCH) {
            if chunk.len() > 1 {
                self.op(op::MARK);
            }
            for item in chunk {
                write(self, item)?;
            }
            self.op(if chunk.len() > 1 { many } else { one });
        }
        Ok(())
    }

    fn seq(&mut self, items: &[Value], depth: usize) -> Result<(), PickleError> {
        items.iter().try_for_each(|v| self.value(v, depth + 1))
    }

    fn tuple(&mut self, items: &[Value], depth: usize) -> Result<(), PickleError> {
        match items.len() {
            0 => self.op(op::EMPTY_TUPLE),
            1..=3 => {
                self.seq(items, depth)?;
                self.op(op::TUPLE1 + items.len() as u8 - 1);
            }
            _ => {
                self.op(op::MARK);
                self.seq(items, depth)?;
                self.op(op::TUPLE);
            }
        }
        Ok(())
    }

    fn value(&mut self, value: &Value, depth: usize) -> Result<(), PickleError> {
        if depth > MAX_DEPTH {
            return Err(PickleError::Unpicklable(format!("value nested deeper than {MAX_DEPTH} levels")));
        }
        match value {
            Value::None => self.op(op::NONE),
            Value::Bool(b) => self.op(if *b { op::NEWTRUE } else { op::NEWFALSE }),
            Value::Int(i) => self.int(*i),
            Value::Float(f) => {
                self.op(op::BINFLOAT);
                self.out.extend(f.to_be_bytes());
            }
            Value::Str(s) => self.str(s),
            Value::Bytes(b) => self.bytes(b),
            Value::List(items) => {
                self.op(op::EMPTY_LIST);
                self.batched(items, op::APPEND, op::APPENDS, |p, v| p.value(v, depth + 1))?;
            }
            Value::Tuple(items) => self.tuple(items, depth)?,
            Value::Dict(pairs) => {
                self.op(op::EMPTY_DICT);
                self.batched(pairs, op::SETITEM, op::SETITEMS, |p, (k, v)| {
                    p.value(k, depth + 1)?;
                    p.value(v, depth + 1)
                })?;
            }
            Value::Set(items) => {
                self.op(op::EMPTY_SET);
                for chunk in items.chunks(BATCH) {
                    self.op(op::MARK);
                    self.seq(chunk, depth)?;
                    self.op(op::ADDITEMS);
                }
            }
            Value::Array(a) => self.array(a, depth)?,
            Value::Object { class, args, state } => {
                self.global(class)?;
                self.tuple(args, depth)?;
                self.op(op::REDUCE);
                if let Some(state) = state {
                    self.value(state, depth + 1)?;
                    self.op(op::BUILD);
                }
            }
            Value::Global(name) => self.global(name)?,
        }
        Ok(())
    }

    /// `_reconstruct(ndarray, (0,), b'b')` then BUILD `(1, shape, dtype, False, data)`.
    fn array(&mut self, a: &NdArray, depth: usize) -> Result<(), PickleError> {
        let n = a.shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
        if n != Some(a.data.len()) {
            return Err(PickleError::Unpicklable(format!(
                "array shape {:?} does not match its {} elements",
                a.shape,
                a.data.len()
            )));
        }
        let enc = encode_array(a);
        self.global(RECONSTRUCT)?;
        self.global("numpy.ndarray")?;
        self.int(0);
        self.op(op::TUPLE1);
        self.bytes(b"b");
        self.op(op::TUPLE3);
        self.op(op::REDUCE);

        self.op(op::MARK);
        self.int(1);
        let shape: Vec<Value> = a
            .shape
            .iter()
            .map(|&d| i64::try_from(d).map(Value::Int))
            .collect::<Result<_, _>>()
            .map_err(|_| PickleError::Unpicklable("array dimension too large".into()))?;
        self.tuple(&shape, depth)?;
        self.dtype(&enc)?;
        self.op(op::NEWFALSE);
        match enc.payload {
            Payload::Bytes(bytes) => self.bytes(&bytes),
            Payload::Objects(items) => {
                self.op(op::EMPTY_LIST);
                self.batched(items, op::APPEND, op::APPENDS, |p, v| p.value(v, depth + 1))?;
            }
        }
        self.op(op::TUPLE);
        self.op(op::BUILD);
        Ok(())
    }

    /// `numpy.dtype(descr, False, True)` + BUILD `(3, order, None, None, None, elsize, align, flags)`.
    fn dtype(&mut self, enc: &Encoded) -> Result<(), PickleError> {
        let key = format!("dtype {}{} {} {} {}", enc.order, enc.descr, enc.elsize, enc.alignment, enc.flags);
        // The memo holds the dtype after its BUILD (same object), as in numpy's own pickles.
        if let Some(&slot) = self.memo.get(&key) {
            self.get(slot);
            return Ok(());
        }
        self.global("numpy.dtype")?;
        self.str(&enc.descr);
        self.op(op::NEWFALSE);
        self.op(op::NEWTRUE);
        self.op(op::TUPLE3);
        self.op(op::REDUCE);
        self.memoize(key);
        self.op(op::MARK);
        self.int(3);
        self.str(enc.order);
        self.op(op::NONE);
        self.op(op::NONE);
        self.op(op::NONE);
        self.int(enc.elsize);
        self.int(enc.alignment);
        self.int(enc.flags);
        self.op(op::TUPLE);
        self.op(op::BUILD);
        Ok(())
    }
}
