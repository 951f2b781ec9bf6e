//! REDUCE / NEWOBJ / BUILD: what calling a pickled global does. numpy arrays, dtypes and scalars
//! and a few builtins are interpreted; every other class becomes a generic object.

use std::rc::Rc;

use super::de::Unpickler;
use super::numpy::{self, Dtype, StateField};
use super::objects::{Entries, Item, Obj};
use super::PickleError;

fn global_name(item: &Item) -> Option<String> {
    match item {
        Item::Ref(s) => match s.0.try_borrow().as_deref() {
            Ok(Obj::Global(name)) => Some(name.clone()),
            _ => None,
        },
        _ => None,
    }
}

/// Raw bytes of a `bytes` item; Python 2 `str` payloads arrive as `Str` when they happen to be
/// valid UTF-8, and their UTF-8 encoding is exactly the original bytes.
fn raw_bytes(item: &Item) -> Option<Rc<[u8]>> {
    match item {
        Item::Bytes(b) => Some(b.clone()),
        Item::Str(s) => Some(Rc::from(s.as_bytes())),
        _ => None,
    }
}

fn as_str(item: &Item) -> Option<&str> {
    match item {
        Item::Str(s) => Some(s),
        _ => None,
    }
}

/// Elements of a list, tuple or set item.
fn sequence(item: &Item) -> Option<Vec<Item>> {
    match item {
        Item::Ref(s) => match s.0.try_borrow().as_deref() {
            Ok(Obj::List(v) | Obj::Tuple(v)) => Some(v.clone()),
            Ok(Obj::Set(e)) => Some(e.pairs.iter().map(|(k, _)| k.clone()).collect()),
            _ => None,
        },
        _ => None,
    }
}

fn dtype(item: &Item) -> Option<Dtype> {
    match item {
        Item::Ref(s) => match s.0.try_borrow().as_deref() {
            Ok(Obj::Dtype(d)) => Some(d.clone()),
            _ => None,
        },
        _ => None,
    }
}

fn state_field(item: &Item) -> StateField {
    match item {
        Item::None => StateField::None,
        Item::Int(i) => StateField::Int(*i),
        Item::Str(s) => StateField::Str(s.to_string()),
        other => match sequence(other) {
            Some(names) => names
                .iter()
                .map(|n| as_str(n).map(str::to_owned))
                .collect::<Option<Vec<_>>>()
                .map_or(StateField::Other, StateField::Names),
            None => StateField::Other,
        },
    }
}

fn set_of(items: Vec<Item>) -> Item {
    let mut set = Entries::default();
    items.into_iter().for_each(|k| set.insert(k, Item::None));
    Item::new(Obj::Set(set))
}

impl Unpickler<'_> {
    fn shape(&self, item: &Item) -> Result<Vec<usize>, PickleError> {
        let dims = match item {
            // numpy accepts a bare int for 1-D shapes.
            Item::Int(_) => vec![item.clone()],
            other => sequence(other).ok_or_else(|| self.err("array shape is not a tuple"))?,
        };
        dims.iter()
            .map(|d| match d {
                Item::Int(n) => usize::try_from(*n).ok(),
                _ => None,
            })
            .collect::<Option<_>>()
            .ok_or_else(|| self.err("array shape must hold non-negative ints"))
    }

    fn dtype_arg(&self, item: Option<&Item>) -> Result<Dtype, PickleError> {
        item.and_then(dtype).ok_or_else(|| self.err("expected a numpy.dtype argument"))
    }

    /// `_codecs.encode(text, encoding)`, which protocol 2 uses for every `bytes` object.
    fn encode(&self, text: &str, encoding: &str) -> Result<Item, PickleError> {
        match encoding.to_ascii_lowercase().replace('_', "-").as_str() {
            "latin1" | "latin-1" | "iso-8859-1" | "l1" => {
                let bytes: Option<Vec<u8>> = text.chars().map(|c| u8::try_from(c).ok()).collect();
                let bytes = bytes.ok_or_else(|| self.err("text is not latin-1"))?;
                Ok(Item::bytes(&bytes))
            }
            "utf-8" | "utf8" => Ok(Item::bytes(text.as_bytes())),
            other => Err(self.err(format!("unsupported encoding '{other}' in _codecs.encode"))),
        }
    }

    /// Calls a global with arguments (REDUCE, INST, OBJ).
    pub(crate) fn reduce(&self, callable: &Item, args: Vec<Item>) -> Result<Item, PickleError> {
        let name = global_name(callable).ok_or_else(|| self.err(format!("cannot call {}", callable.kind())))?;
        let generic = |args| Ok(Item::new(Obj::Object { class: name.clone(), args, state: None }));
        match name.as_str() {
            // Subclasses (np.matrix, np.memmap) share ndarray's state layout.
            "numpy.core.multiarray._reconstruct" | "numpy._core.multiarray._reconstruct" => {
                Ok(Item::new(Obj::PendingArray))
            }
            "numpy.dtype" => match args.first().and_then(as_str) {
                Some(descr) => Ok(Item::new(Obj::Dtype(Dtype::new(descr.to_owned())))),
                None => Err(self.err("numpy.dtype needs a type string")),
            },
            "numpy.core.multiarray.scalar" | "numpy._core.multiarray.scalar" => {
                let dtype = self.dtype_arg(args.first())?;
                let data = args.get(1).ok_or_else(|| self.err("scalar without data"))?;
                if dtype.is_object() {
                    return Ok(data.clone());
                }
                let bytes = raw_bytes(data).ok_or_else(|| self.err("scalar data is not bytes"))?;
                Ok(Item::from_scalar(numpy::decode_scalar(&dtype, &bytes, self.op_start)?))
            }
            // Protocol 5 pickles contiguous arrays as _frombuffer(buffer, dtype, shape, order).
            "numpy.core.numeric._frombuffer" | "numpy._core.numeric._frombuffer" => {
                let [buf, dt, shape, order] = args.as_slice() else {
                    return Err(self.err("_frombuffer takes 4 arguments"));
                };
                let bytes = raw_bytes(buf).ok_or_else(|| self.err("array buffer is not bytes"))?;
                let dtype = self.dtype_arg(Some(dt))?;
                let shape = self.shape(shape)?;
                let fortran = as_str(order) == Some("F");
                let array = numpy::decode_buffer(&dtype, &shape, fortran, &bytes, self.op_start)?;
                Ok(Item::new(Obj::Array(array)))
            }
            "_codecs.encode" => match args.as_slice() {
                [Item::Str(text), Item::Str(enc)] => self.encode(text, enc),
                [Item::Str(text)] => self.encode(text, "utf-8"),
                _ => Err(self.err("_codecs.encode needs (str, encoding)")),
            },
            "builtins.bytes" | "builtins.bytearray" => match args.as_slice() {
                [] => Ok(Item::bytes(&[])),
                [b @ Item::Bytes(_)] => Ok(b.clone()),
                [Item::Str(text), Item::Str(enc)] => self.encode(text, enc),
                _ => generic(args),
            },
            "builtins.set" | "builtins.frozenset" => match args.as_slice() {
                [] => Ok(set_of(Vec::new())),
                [items] => match sequence(items) {
                    Some(items) => Ok(set_of(items)),
                    None => generic(args),
                },
                _ => generic(args),
            },
            // dict subclasses: the items follow as SETITEMS; the factory / class is dropped.
            "collections.OrderedDict" | "collections.defaultdict" | "collections.Counter" => {
                let mut dict = Entries::default();
                if name != "collections.defaultdict" {
                    if let Some(arg) = args.first() {
                        self.copy_pairs(arg, &mut dict)?;
                    }
                }
                Ok(Item::new(Obj::Dict(dict)))
            }
            // Protocol 0/1 pickles of plain classes: _reconstructor(cls, base, state).
            "copyreg._reconstructor" => {
                let [class, base, state] = args.as_slice() else {
                    return Err(self.err("_reconstructor takes 3 arguments"));
                };
                match global_name(base).as_deref() {
                    Some("builtins.dict") => Ok(Item::new(Obj::Dict(Entries::default()))),
                    Some("builtins.list") => Ok(Item::new(Obj::List(Vec::new()))),
                    _ => Ok(Item::new(Obj::Object {
                        class: global_name(class).unwrap_or_else(|| class.kind()),
                        args: match state {
                            Item::None => Vec::new(),
                            other => vec![other.clone()],
                        },
                        state: None,
                    })),
                }
            }
            _ => generic(args),
        }
    }

    /// Copies a dict or a list of pairs into `dict` (OrderedDict / Counter arguments).
    fn copy_pairs(&self, arg: &Item, dict: &mut Entries) -> Result<(), PickleError> {
        if let Item::Ref(s) = arg {
            if let Ok(Obj::Dict(d)) = s.0.try_borrow().as_deref() {
                for (k, v) in &d.pairs {
                    dict.insert(k.clone(), v.clone());
                }
                return Ok(());
            }
        }
        let pairs = sequence(arg).ok_or_else(|| self.err("expected a dict or a list of pairs"))?;
        for pair in pairs {
            match sequence(&pair).as_deref() {
                Some([k, v]) => dict.insert(k.clone(), v.clone()),
                _ => return Err(self.err("expected a (key, value) pair")),
            }
        }
        Ok(())
    }

    /// `cls.__new__(cls, *args)` (NEWOBJ, NEWOBJ_EX).
    pub(crate) fn new_object(&self, class: &Item, args: Vec<Item>) -> Result<Item, PickleError> {
        let class = global_name(class).ok_or_else(|| self.err(format!("{} is not a class", class.kind())))?;
        Ok(Item::new(Obj::Object { class, args, state: None }))
    }

    /// BUILD: `target.__setstate__(state)`.
    pub(crate) fn build(&self, target: &Item, state: Item) -> Result<(), PickleError> {
        let Item::Ref(shared) = target else {
            return Err(self.err(format!("cannot BUILD {}", target.kind())));
        };
        let current = match shared.0.try_borrow() {
            Ok(obj) => obj.kind(),
            Err(_) => return Err(self.err("object is already borrowed")),
        };
        // Work out the new contents while nothing is borrowed mutably (the state may refer to
        // the target itself).
        let borrowed = shared.0.try_borrow();
        let new_obj = match borrowed.as_deref() {
            Ok(Obj::Dtype(d)) => {
                let mut d = d.clone();
                let fields: Vec<StateField> = self.tuple_items(&state)?.iter().map(state_field).collect();
                numpy::set_dtype_state(&mut d, &fields);
                Some(Obj::Dtype(d))
            }
            Ok(Obj::PendingArray) => Some(self.array_state(&state)?),
            Ok(Obj::Object { .. }) => None,
            // Instances of dict/list subclasses: their attribute state is not kept.
            Ok(Obj::Dict(_) | Obj::List(_)) => return Ok(()),
            _ => return Err(self.err(format!("cannot BUILD {current}"))),
        };
        drop(borrowed);
        let mut obj = shared.0.try_borrow_mut().map_err(|_| self.err("object is already borrowed"))?;
        match (new_obj, &mut *obj) {
            (Some(new), _) => *obj = new,
            (None, Obj::Object { state: slot, .. }) => *slot = Some(state),
            (None, _) => return Err(self.err(format!("cannot BUILD {current}"))),
        }
        Ok(())
    }

    /// ndarray state: `(version, shape, dtype, is_fortran, data)` (older pickles omit version).
    fn array_state(&self, state: &Item) -> Result<Obj, PickleError> {
        let items = self.tuple_items(state)?;
        let fields = match items.as_slice() {
            [_, rest @ ..] if rest.len() == 4 => rest,
            all => all,
        };
        let [shape, dt, fortran, data] = fields else {
            return Err(self.err("ndarray state must be a 4- or 5-tuple"));
        };
        let shape = self.shape(shape)?;
        let dtype = self.dtype_arg(Some(dt))?;
        let fortran = matches!(fortran, Item::Bool(true)) || matches!(fortran, Item::Int(i) if *i != 0);
        if dtype.is_object() {
            // Object arrays pickle their elements as a list, in C order.
            let items = sequence(data).ok_or_else(|| self.err("object array data is not a list"))?;
            let n = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
            if n != Some(items.len()) {
                return Err(self.err(format!("object array of shape {shape:?} has {} elements", items.len())));
            }
            return Ok(Obj::ObjectArray { shape, items });
        }
        let bytes = raw_bytes(data).ok_or_else(|| self.err("array data is not bytes"))?;
        let array = numpy::decode_buffer(&dtype, &shape, fortran, &bytes, self.op_start)?;
        Ok(Obj::Array(array))
    }
}
