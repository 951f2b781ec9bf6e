//! numpy dtypes and raw array buffers: decoding what `ndarray.__reduce__` pickles, and encoding
//! arrays the way numpy does.

use super::{ArrayData, NdArray, PickleError, Value};

/// A numpy dtype as pickled: `numpy.dtype(descr, False, True)` then BUILD with
/// `(version, byteorder, subarray, names, fields, elsize, alignment, flags[, metadata])`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Dtype {
    /// e.g. `"f8"`, `"U7"`, `"O8"`, `"V16"`.
    pub descr: String,
    /// `<`, `>`, `|` or `=`; `|` until BUILD says otherwise.
    pub order: char,
    /// Item size from the state, for flexible types (`U`, `S`, `V`).
    pub elsize: Option<usize>,
    /// Why the state makes this dtype unsupported (fields, subarray, datetime metadata).
    pub unsupported: Option<String>,
}

/// Element kinds this module can decode.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Bool,
    Int(usize),
    UInt(usize),
    Float(usize),
    /// UCS-4 string with this many characters.
    Str(usize),
    /// Byte string with this many bytes.
    Bytes(usize),
    Object,
}

impl Kind {
    /// Bytes per element; `kind()` guarantees that this does not overflow.
    fn itemsize(self) -> usize {
        match self {
            Kind::Bool => 1,
            Kind::Int(n) | Kind::UInt(n) | Kind::Float(n) | Kind::Bytes(n) => n,
            Kind::Str(n) => 4 * n,
            Kind::Object => 8,
        }
    }
}

impl Dtype {
    pub fn new(descr: String) -> Self {
        Self { descr, order: '|', elsize: None, unsupported: None }
    }

    /// numpy's spelling, e.g. `<f8`, `|b1`, `>U3`.
    pub fn display(&self) -> String {
        format!("{}{}", self.order, self.descr)
    }

    fn unsupported(&self, offset: usize, reason: impl Into<String>) -> PickleError {
        PickleError::UnsupportedDtype { dtype: self.display(), reason: reason.into(), offset }
    }

    fn kind(&self, offset: usize) -> Result<Kind, PickleError> {
        if let Some(reason) = &self.unsupported {
            return Err(self.unsupported(offset, reason.clone()));
        }
        let mut chars = self.descr.chars();
        let letter = chars.next().unwrap_or(' ');
        let digits = chars.as_str();
        let size: Option<usize> = if digits.is_empty() { None } else { digits.parse().ok() };
        let fixed = |n: usize| size == Some(n);
        let kind = match letter {
            'b' if fixed(1) => Kind::Bool,
            '?' if size.is_none() => Kind::Bool,
            'i' if [1, 2, 4, 8].iter().any(|&n| fixed(n)) => Kind::Int(size.unwrap_or(0)),
            'u' if [1, 2, 4, 8].iter().any(|&n| fixed(n)) => Kind::UInt(size.unwrap_or(0)),
            'f' if [2, 4, 8].iter().any(|&n| fixed(n)) => Kind::Float(size.unwrap_or(0)),
            'O' => Kind::Object,
            'U' => match (self.elsize, size) {
                (Some(bytes), _) if bytes.is_multiple_of(4) => Kind::Str(bytes / 4),
                (None, Some(chars)) => Kind::Str(chars),
                _ => return Err(self.unsupported(offset, "bad unicode item size")),
            },
            'S' | 'a' => match self.elsize.or(size) {
                Some(n) => Kind::Bytes(n),
                None => return Err(self.unsupported(offset, "bad bytes item size")),
            },
            'c' => return Err(self.unsupported(offset, "complex numbers are not supported")),
            'M' | 'm' => return Err(self.unsupported(offset, "datetimes are not supported")),
            'V' => return Err(self.unsupported(offset, "void/record dtypes are not supported")),
            _ => return Err(self.unsupported(offset, "unknown type code")),
        };
        // Real item sizes are small; this also keeps `itemsize` from overflowing.
        match kind {
            Kind::Str(n) | Kind::Bytes(n) if n > 1 << 32 => Err(self.unsupported(offset, "item size too large")),
            _ => Ok(kind),
        }
    }

    /// Whether values are big-endian (`=` is taken as little-endian: every machine that
    /// writes these files is).
    fn big_endian(&self) -> bool {
        self.order == '>'
    }

    pub fn is_object(&self) -> bool {
        self.descr.starts_with('O')
    }
}

/// Applies the dtype state tuple of BUILD.
pub(crate) fn set_dtype_state(dtype: &mut Dtype, state: &[StateField]) {
    // Versions 3 and 4 (numpy >= 1.7); older pickles put the byte order second as well.
    if let Some(StateField::Str(order)) = state.get(1) {
        if let Some(c) = order.chars().next() {
            dtype.order = c;
        }
    }
    if matches!(state.get(2), Some(f) if *f != StateField::None) {
        dtype.unsupported = Some("sub-array dtypes are not supported".into());
    }
    if let Some(StateField::Names(names)) = state.get(3) {
        dtype.unsupported = Some(format!("structured dtypes (fields {}) are not supported", names.join(", ")));
    } else if matches!(state.get(3), Some(f) if *f != StateField::None) {
        dtype.unsupported = Some("structured dtypes are not supported".into());
    }
    if let Some(StateField::Int(n)) = state.get(5) {
        dtype.elsize = usize::try_from(*n).ok();
    }
}

/// The parts of a dtype state tuple this module looks at.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum StateField {
    None,
    Int(i64),
    Str(String),
    /// Field names of a structured dtype.
    Names(Vec<String>),
    Other,
}

fn product(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

/// Decodes a raw numpy buffer (`tobytes()` in C order, or Fortran order when `fortran`).
pub(crate) fn decode_buffer(
    dtype: &Dtype,
    shape: &[usize],
    fortran: bool,
    data: &[u8],
    offset: usize,
) -> Result<NdArray, PickleError> {
    let kind = dtype.kind(offset)?;
    if kind == Kind::Object {
        return Err(PickleError::invalid(offset, "object array without a list of elements"));
    }
    let n = product(shape).ok_or_else(|| PickleError::invalid(offset, format!("array shape {shape:?} overflows")))?;
    let expected = n.checked_mul(kind.itemsize());
    // Zero-width items (U0/S0) would let a tiny pickle claim a huge element count.
    if expected != Some(data.len()) || (kind.itemsize() == 0 && n > 1 << 20) {
        return Err(PickleError::invalid(
            offset,
            format!(
                "array data is {} bytes, expected {shape:?} x {} ({} bytes per item)",
                data.len(),
                dtype.display(),
                kind.itemsize()
            ),
        ));
    }
    let be = dtype.big_endian();
    macro_rules! num {
        ($t:ty, $variant:ident) => {
            ArrayData::$variant(
                data.chunks_exact(std::mem::size_of::<$t>())
                    .map(|c| {
                        let b = c.try_into().expect("chunk size");
                        if be {
                            <$t>::from_be_bytes(b)
                        } else {
                            <$t>::from_le_bytes(b)
                        }
                    })
                    .collect(),
            )
        };
    }
    let values = match kind {
        Kind::Bool => ArrayData::Bool(data.iter().map(|&b| b != 0).collect()),
        Kind::Int(1) => num!(i8, I8),
        Kind::Int(2) => num!(i16, I16),
        Kind::Int(4) => num!(i32, I32),
        Kind::Int(_) => num!(i64, I64),
        Kind::UInt(1) => num!(u8, U8),
        Kind::UInt(2) => num!(u16, U16),
        Kind::UInt(4) => num!(u32, U32),
        Kind::UInt(_) => num!(u64, U64),
        Kind::Float(2) => match num!(u16, U16) {
            ArrayData::U16(bits) => ArrayData::F32(bits.into_iter().map(f16_to_f32).collect()),
            _ => unreachable!("num! yields U16"),
        },
        Kind::Float(4) => num!(f32, F32),
        Kind::Float(_) => num!(f64, F64),
        Kind::Str(chars) => ArrayData::Str(decode_ucs4(data, n, chars, be, offset)?),
        Kind::Bytes(size) => ArrayData::Bytes(
            (0..n)
                .map(|i| {
                    let item = &data[i * size..(i + 1) * size];
                    let end = item.iter().rposition(|&b| b != 0).map_or(0, |p| p + 1);
                    item[..end].to_vec()
                })
                .collect(),
        ),
        Kind::Object => unreachable!("handled above"),
    };
    let values = if fortran && shape.len() > 1 { fortran_to_c(values, shape) } else { values };
    Ok(NdArray { shape: shape.to_vec(), data: values })
}

fn decode_ucs4(data: &[u8], n: usize, chars: usize, be: bool, offset: usize) -> Result<Vec<String>, PickleError> {
    (0..n)
        .map(|i| {
            let item = &data[i * chars * 4..(i + 1) * chars * 4];
            let mut s: String = item
                .chunks_exact(4)
                .map(|c| {
                    let b = [c[0], c[1], c[2], c[3]];
                    let code = if be { u32::from_be_bytes(b) } else { u32::from_le_bytes(b) };
                    char::from_u32(code).ok_or_else(|| {
                        PickleError::invalid(offset, format!("invalid code point {code:#x} in unicode array"))
                    })
                })
                .collect::<Result<_, _>>()?;
            // numpy pads with NULs and strips them when reading items.
            s.truncate(s.trim_end_matches('\0').len());
            Ok(s)
        })
        .collect()
}

/// IEEE half → single precision (exact).
fn f16_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exp = u32::from((h >> 10) & 0x1f);
    let mant = u32::from(h & 0x3ff);
    let bits = match (exp, mant) {
        (0, 0) => sign,
        // Subnormal: value = mant * 2^-24, exactly representable in f32.
        (0, m) => return (m as f32) * 2f32.powi(-24) * sign_factor(sign),
        (0x1f, m) => sign | 0x7f80_0000 | (m << 13),
        (e, m) => sign | ((e + 127 - 15) << 23) | (m << 13),
    };
    f32::from_bits(bits)
}

fn sign_factor(sign: u32) -> f32 {
    if sign == 0 {
        1.0
    } else {
        -1.0
    }
}

/// Reorders Fortran-ordered elements to C order.
fn fortran_to_c(data: ArrayData, shape: &[usize]) -> ArrayData {
    fn reorder<T: Clone>(v: Vec<T>, shape: &[usize]) -> Vec<T> {
        if v.is_empty() {
            return v;
        }
        // Fortran strides: the first axis varies fastest.
        let mut strides = vec![1usize; shape.len()];
        for k in 1..shape.len() {
            strides[k] = strides[k - 1] * shape[k - 1];
        }
        let mut idx = vec![0usize; shape.len()];
        let mut out = Vec::with_capacity(v.len());
        for _ in 0..v.len() {
            let src: usize = idx.iter().zip(&strides).map(|(i, s)| i * s).sum();
            out.push(v[src].clone());
            // Advance the C-order multi-index (last axis fastest).
            for k in (0..shape.len()).rev() {
                idx[k] += 1;
                if idx[k] < shape[k] {
                    break;
                }
                idx[k] = 0;
            }
        }
        out
    }
    match data {
        ArrayData::Bool(v) => ArrayData::Bool(reorder(v, shape)),
        ArrayData::I8(v) => ArrayData::I8(reorder(v, shape)),
        ArrayData::I16(v) => ArrayData::I16(reorder(v, shape)),
        ArrayData::I32(v) => ArrayData::I32(reorder(v, shape)),
        ArrayData::I64(v) => ArrayData::I64(reorder(v, shape)),
        ArrayData::U8(v) => ArrayData::U8(reorder(v, shape)),
        ArrayData::U16(v) => ArrayData::U16(reorder(v, shape)),
        ArrayData::U32(v) => ArrayData::U32(reorder(v, shape)),
        ArrayData::U64(v) => ArrayData::U64(reorder(v, shape)),
        ArrayData::F32(v) => ArrayData::F32(reorder(v, shape)),
        ArrayData::F64(v) => ArrayData::F64(reorder(v, shape)),
        ArrayData::Str(v) => ArrayData::Str(reorder(v, shape)),
        ArrayData::Bytes(v) => ArrayData::Bytes(reorder(v, shape)),
        ArrayData::Object(v) => ArrayData::Object(reorder(v, shape)),
    }
}

/// Decodes `numpy.core.multiarray.scalar(dtype, bytes)` to a plain value.
pub(crate) fn decode_scalar(dtype: &Dtype, data: &[u8], offset: usize) -> Result<Value, PickleError> {
    let array = decode_buffer(dtype, &[], false, data, offset)?;
    Ok(match array.data {
        ArrayData::Bool(v) => Value::Bool(v[0]),
        ArrayData::F32(v) => Value::Float(v[0].into()),
        ArrayData::F64(v) => Value::Float(v[0]),
        ArrayData::Str(mut v) => Value::Str(v.swap_remove(0)),
        ArrayData::Bytes(mut v) => Value::Bytes(v.swap_remove(0)),
        ArrayData::U64(v) => Value::Int(i64::try_from(v[0]).map_err(|_| PickleError::IntOverflow { offset })?),
        other => NdArray::from_vec(other)
            .to_i64_vec()
            .and_then(|v| v.first().copied())
            .map(Value::Int)
            .ok_or_else(|| PickleError::invalid(offset, "bad numpy scalar"))?,
    })
}

/// How the writer pickles an array: dtype descr + state fields, then the payload.
pub(crate) struct Encoded<'a> {
    pub descr: String,
    pub order: &'static str,
    pub elsize: i64,
    pub alignment: i64,
    pub flags: i64,
    pub payload: Payload<'a>,
}

pub(crate) enum Payload<'a> {
    Bytes(Vec<u8>),
    Objects(&'a [Value]),
}

/// Encodes an array exactly like numpy 1.x/2.x pickles it (little-endian, C order).
pub(crate) fn encode_array(a: &NdArray) -> Encoded<'_> {
    macro_rules! le {
        ($v:expr) => {
            $v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>()
        };
    }
    let fixed = |descr: &str, order, bytes| Encoded {
        descr: descr.to_owned(),
        order,
        elsize: -1,
        alignment: -1,
        flags: 0,
        payload: Payload::Bytes(bytes),
    };
    match &a.data {
        ArrayData::Bool(v) => fixed("b1", "|", v.iter().map(|&b| u8::from(b)).collect()),
        ArrayData::I8(v) => fixed("i1", "|", le!(v)),
        ArrayData::I16(v) => fixed("i2", "<", le!(v)),
        ArrayData::I32(v) => fixed("i4", "<", le!(v)),
        ArrayData::I64(v) => fixed("i8", "<", le!(v)),
        ArrayData::U8(v) => fixed("u1", "|", v.clone()),
        ArrayData::U16(v) => fixed("u2", "<", le!(v)),
        ArrayData::U32(v) => fixed("u4", "<", le!(v)),
        ArrayData::U64(v) => fixed("u8", "<", le!(v)),
        ArrayData::F32(v) => fixed("f4", "<", le!(v)),
        ArrayData::F64(v) => fixed("f8", "<", le!(v)),
        ArrayData::Str(v) => {
            // numpy never makes a zero-width unicode array: np.array(['']) is <U1.
            let chars = v.iter().map(|s| s.chars().count()).max().unwrap_or(0).max(1);
            let mut bytes = Vec::with_capacity(v.len() * chars * 4);
            for s in v {
                let mut n = 0;
                for c in s.chars() {
                    bytes.extend_from_slice(&u32::from(c).to_le_bytes());
                    n += 1;
                }
                bytes.resize(bytes.len() + (chars - n) * 4, 0);
            }
            Encoded {
                descr: format!("U{chars}"),
                order: "<",
                elsize: 4 * chars as i64,
                alignment: 4,
                flags: 8,
                payload: Payload::Bytes(bytes),
            }
        }
        ArrayData::Bytes(v) => {
            let size = v.iter().map(Vec::len).max().unwrap_or(0).max(1);
            let mut bytes = Vec::with_capacity(v.len() * size);
            for b in v {
                bytes.extend_from_slice(b);
                bytes.resize(bytes.len() + size - b.len(), 0);
            }
            Encoded {
                descr: format!("S{size}"),
                order: "|",
                elsize: size as i64,
                alignment: 1,
                flags: 0,
                payload: Payload::Bytes(bytes),
            }
        }
        ArrayData::Object(v) => Encoded {
            descr: "O8".into(),
            order: "|",
            elsize: -1,
            alignment: -1,
            // NPY_OBJECT_DTYPE_FLAGS, as numpy writes them.
            flags: 63,
            payload: Payload::Objects(v),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_floats() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x8001), -(2f32.powi(-24)));
        assert!(f16_to_f32(0x7c00).is_infinite());
        assert!(f16_to_f32(0x7e00).is_nan());
    }

    #[test]
    fn fortran_reorder() {
        // [[0, 1, 2], [3, 4, 5]] stored column-major.
        let f = ArrayData::I64(vec![0, 3, 1, 4, 2, 5]);
        assert_eq!(fortran_to_c(f, &[2, 3]), ArrayData::I64(vec![0, 1, 2, 3, 4, 5]));
    }

    #[test]
    fn structured_dtype_is_rejected() {
        let mut d = Dtype::new("V8".into());
        set_dtype_state(
            &mut d,
            &[
                StateField::Int(3),
                StateField::Str("|".into()),
                StateField::None,
                StateField::Names(vec!["x".into(), "y".into()]),
                StateField::Other,
                StateField::Int(8),
            ],
        );
        let err = decode_buffer(&d, &[1], false, &[0; 8], 42).unwrap_err();
        assert_eq!(
            err.to_string(),
            "unsupported numpy dtype '|V8' at byte 42: structured dtypes (fields x, y) are not supported"
        );
    }
}
