//! The owned value tree a pickle decodes to (and that the writer encodes).

use super::PickleError;

/// A decoded Python object.
///
/// numpy scalars (`np.float32(1.5)`, `np.int64(3)`, `np.True_`, `np.str_('a')`) are decoded to the
/// plain variant of the same kind (`Float`, `Int`, `Bool`, `Str`, `Bytes`), because callers treat
/// them exactly like Python numbers and strings. numpy arrays (including 0-d arrays) become
/// [`Value::Array`].
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    /// `bytes` and `bytearray`, and Python 2 `str` that is not valid UTF-8.
    Bytes(Vec<u8>),
    List(Vec<Value>),
    Tuple(Vec<Value>),
    /// Insertion-ordered; keys are unique.
    Dict(Vec<(Value, Value)>),
    /// `set` and `frozenset`.
    Set(Vec<Value>),
    Array(NdArray),
    /// An instance of a class this reader does not know: `class` is `"module.qualname"`, `args`
    /// what the pickle passed to the class (REDUCE / NEWOBJ; NEWOBJ_EX appends its keyword
    /// dict when non-empty) and `state` what BUILD set. The writer emits it as
    /// `class(*args)` followed by BUILD(state).
    Object {
        class: String,
        args: Vec<Value>,
        state: Option<Box<Value>>,
    },
    /// A bare reference to a global (class or function), `"module.qualname"`.
    Global(String),
}

/// A numpy array in C (row-major) order.
#[derive(Debug, Clone, PartialEq)]
pub struct NdArray {
    pub shape: Vec<usize>,
    pub data: ArrayData,
}

/// The elements of an [`NdArray`], in C order, in native byte order.
///
/// `float16` arrays are widened to `F32` when read.
#[derive(Debug, Clone, PartialEq)]
pub enum ArrayData {
    Bool(Vec<bool>),
    I8(Vec<i8>),
    I16(Vec<i16>),
    I32(Vec<i32>),
    I64(Vec<i64>),
    U8(Vec<u8>),
    U16(Vec<u16>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    F32(Vec<f32>),
    F64(Vec<f64>),
    /// numpy `<U n` arrays, trailing NULs stripped.
    Str(Vec<String>),
    /// numpy `S n` arrays, trailing NULs stripped.
    Bytes(Vec<Vec<u8>>),
    /// numpy `object` arrays.
    Object(Vec<Value>),
}

macro_rules! array_data_from {
    ($($t:ty => $v:ident),* $(,)?) => {$(
        impl From<Vec<$t>> for ArrayData {
            fn from(v: Vec<$t>) -> Self {
                ArrayData::$v(v)
            }
        }
    )*};
}
array_data_from!(
    bool => Bool, i8 => I8, i16 => I16, i32 => I32, i64 => I64, u8 => U8, u16 => U16,
    u32 => U32, u64 => U64, f32 => F32, f64 => F64, String => Str, Vec<u8> => Bytes,
    Value => Object,
);

/// Expands `$body` once per integer variant, with the vector bound to `$v`.
macro_rules! int_arms {
    ($data:expr, $v:ident => $body:expr, $($rest:tt)*) => {
        match $data {
            ArrayData::I8($v) => $body,
            ArrayData::I16($v) => $body,
            ArrayData::I32($v) => $body,
            ArrayData::I64($v) => $body,
            ArrayData::U8($v) => $body,
            ArrayData::U16($v) => $body,
            ArrayData::U32($v) => $body,
            ArrayData::U64($v) => $body,
            $($rest)*
        }
    };
}

impl ArrayData {
    /// Number of elements.
    pub fn len(&self) -> usize {
        int_arms!(self, v => v.len(),
            Self::Bool(v) => v.len(),
            Self::F32(v) => v.len(),
            Self::F64(v) => v.len(),
            Self::Str(v) => v.len(),
            Self::Bytes(v) => v.len(),
            Self::Object(v) => v.len(),
        )
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The numpy name of the element type (`"float32"`, `"int64"`, `"str"`, `"object"`...).
    pub fn dtype_name(&self) -> &'static str {
        match self {
            Self::Bool(_) => "bool",
            Self::I8(_) => "int8",
            Self::I16(_) => "int16",
            Self::I32(_) => "int32",
            Self::I64(_) => "int64",
            Self::U8(_) => "uint8",
            Self::U16(_) => "uint16",
            Self::U32(_) => "uint32",
            Self::U64(_) => "uint64",
            Self::F32(_) => "float32",
            Self::F64(_) => "float64",
            Self::Str(_) => "str",
            Self::Bytes(_) => "bytes",
            Self::Object(_) => "object",
        }
    }
}

impl NdArray {
    /// Checks that `shape` matches the number of elements.
    pub fn new(shape: Vec<usize>, data: impl Into<ArrayData>) -> Result<Self, PickleError> {
        let data = data.into();
        let n = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
        if n != Some(data.len()) {
            return Err(PickleError::Unpicklable(format!(
                "array shape {shape:?} does not match its {} elements",
                data.len()
            )));
        }
        Ok(Self { shape, data })
    }

    /// A 1-D array.
    pub fn from_vec(data: impl Into<ArrayData>) -> Self {
        let data = data.into();
        Self { shape: vec![data.len()], data }
    }

    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    pub fn ndim(&self) -> usize {
        self.shape.len()
    }

    /// Total number of elements (product of the shape).
    pub fn len(&self) -> usize {
        self.data.len()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// See [`ArrayData::dtype_name`].
    pub fn dtype_name(&self) -> &'static str {
        self.data.dtype_name()
    }

    /// Elements as `f64` for bool, integer, float and all-numeric object arrays.
    pub fn to_f64_vec(&self) -> Option<Vec<f64>> {
        // i64/u64 beyond 2^53 round, exactly like numpy's astype(float64).
        int_arms!(&self.data, v => Some(v.iter().map(|&x| x as f64).collect()),
            ArrayData::Bool(v) => Some(v.iter().map(|&b| f64::from(u8::from(b))).collect()),
            ArrayData::F32(v) => Some(v.iter().map(|&x| f64::from(x)).collect()),
            ArrayData::F64(v) => Some(v.clone()),
            ArrayData::Object(v) => v.iter().map(Value::as_f64).collect(),
            ArrayData::Str(_) | ArrayData::Bytes(_) => None,
        )
    }

    /// Elements as `f32` (rounded from wider types), see [`Self::to_f64_vec`].
    pub fn to_f32_vec(&self) -> Option<Vec<f32>> {
        match &self.data {
            ArrayData::F32(v) => Some(v.clone()),
            _ => Some(self.to_f64_vec()?.into_iter().map(|x| x as f32).collect()),
        }
    }

    /// Elements as `i64` for bool, integer and all-int object arrays; `None` for floats or
    /// `uint64` values above `i64::MAX`.
    pub fn to_i64_vec(&self) -> Option<Vec<i64>> {
        match &self.data {
            ArrayData::Bool(v) => Some(v.iter().map(|&b| i64::from(b)).collect()),
            ArrayData::U64(v) => v.iter().map(|&x| i64::try_from(x).ok()).collect(),
            ArrayData::Object(v) => v
                .iter()
                .map(|x| match x {
                    Value::Bool(b) => Some(i64::from(*b)),
                    other => other.as_i64(),
                })
                .collect(),
            ArrayData::I8(v) => Some(v.iter().map(|&x| i64::from(x)).collect()),
            ArrayData::I16(v) => Some(v.iter().map(|&x| i64::from(x)).collect()),
            ArrayData::I32(v) => Some(v.iter().map(|&x| i64::from(x)).collect()),
            ArrayData::I64(v) => Some(v.clone()),
            ArrayData::U8(v) => Some(v.iter().map(|&x| i64::from(x)).collect()),
            ArrayData::U16(v) => Some(v.iter().map(|&x| i64::from(x)).collect()),
            ArrayData::U32(v) => Some(v.iter().map(|&x| i64::from(x)).collect()),
            _ => None,
        }
    }

    /// Elements as strings for `U` arrays, UTF-8 `S` arrays and object arrays of `str`.
    pub fn to_strings(&self) -> Option<Vec<String>> {
        match &self.data {
            ArrayData::Str(v) => Some(v.clone()),
            ArrayData::Bytes(v) => v.iter().map(|b| String::from_utf8(b.clone()).ok()).collect(),
            ArrayData::Object(v) => v.iter().map(|x| x.as_str().map(str::to_owned)).collect(),
            _ => None,
        }
    }

    /// The rows of a 2-D numeric array as `f64` (e.g. `(N, 7)` boxes); `None` otherwise.
    pub fn to_f64_rows(&self) -> Option<Vec<Vec<f64>>> {
        let &[rows, cols] = self.shape.as_slice() else {
            return None;
        };
        let flat = self.to_f64_vec()?;
        if cols == 0 {
            return Some(vec![Vec::new(); rows]);
        }
        Some(flat.chunks(cols).map(<[f64]>::to_vec).collect())
    }
}

impl Value {
    /// Looks up a string key in a dict; `None` for other values or a missing key.
    pub fn get(&self, key: &str) -> Option<&Value> {
        self.as_dict()?.iter().find(|(k, _)| k.as_str() == Some(key)).map(|(_, v)| v)
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }

    pub fn as_bytes(&self) -> Option<&[u8]> {
        match self {
            Value::Bytes(b) => Some(b),
            _ => None,
        }
    }

    pub fn as_bool(&self) -> Option<bool> {
        match self {
            Value::Bool(b) => Some(*b),
            _ => None,
        }
    }

    /// `Int`, `Float` or a 0-d numeric array as `f64`.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Int(i) => Some(*i as f64),
            Value::Float(f) => Some(*f),
            Value::Array(a) if a.shape.is_empty() => a.to_f64_vec()?.first().copied(),
            _ => None,
        }
    }

    /// `Int` or a 0-d integer array as `i64`.
    pub fn as_i64(&self) -> Option<i64> {
        match self {
            Value::Int(i) => Some(*i),
            Value::Array(a) if a.shape.is_empty() => a.to_i64_vec()?.first().copied(),
            _ => None,
        }
    }

    /// Elements of a `List` or `Tuple`.
    pub fn as_list(&self) -> Option<&[Value]> {
        match self {
            Value::List(v) | Value::Tuple(v) => Some(v),
            _ => None,
        }
    }

    pub fn as_dict(&self) -> Option<&[(Value, Value)]> {
        match self {
            Value::Dict(v) => Some(v),
            _ => None,
        }
    }

    pub fn as_array(&self) -> Option<&NdArray> {
        match self {
            Value::Array(a) => Some(a),
            _ => None,
        }
    }

    pub fn is_none(&self) -> bool {
        matches!(self, Value::None)
    }

    /// Short Python-ish type name for error messages (`"dict"`, `"ndarray[float32]"`...).
    pub fn type_name(&self) -> String {
        match self {
            Value::None => "None".into(),
            Value::Bool(_) => "bool".into(),
            Value::Int(_) => "int".into(),
            Value::Float(_) => "float".into(),
            Value::Str(_) => "str".into(),
            Value::Bytes(_) => "bytes".into(),
            Value::List(_) => "list".into(),
            Value::Tuple(_) => "tuple".into(),
            Value::Dict(_) => "dict".into(),
            Value::Set(_) => "set".into(),
            Value::Array(a) => format!("ndarray[{}]", a.dtype_name()),
            Value::Object { class, .. } => class.clone(),
            Value::Global(name) => format!("global {name}"),
        }
    }

    /// A dict with string keys, in the given order.
    pub fn dict<K: Into<String>>(pairs: impl IntoIterator<Item = (K, Value)>) -> Value {
        Value::Dict(pairs.into_iter().map(|(k, v)| (Value::Str(k.into()), v)).collect())
    }
}

macro_rules! value_from {
    ($($t:ty => |$x:ident| $e:expr),* $(,)?) => {$(
        impl From<$t> for Value {
            fn from($x: $t) -> Self {
                $e
            }
        }
    )*};
}
value_from!(
    bool => |x| Value::Bool(x),
    i32 => |x| Value::Int(x.into()),
    i64 => |x| Value::Int(x),
    u32 => |x| Value::Int(x.into()),
    f32 => |x| Value::Float(x.into()),
    f64 => |x| Value::Float(x),
    &str => |x| Value::Str(x.to_owned()),
    String => |x| Value::Str(x),
    Vec<u8> => |x| Value::Bytes(x),
    Vec<Value> => |x| Value::List(x),
    NdArray => |x| Value::Array(x),
);
