//! The unpickler's working representation: containers are shared and mutable
//! (`Rc<RefCell<..>>`) so that memo references (GET) observe later APPENDS/SETITEMS/BUILD, as in
//! Python. The result is converted to an owned [`Value`] tree once STOP is reached.

use std::cell::RefCell;
use std::collections::{HashMap, HashSet};
use std::rc::{Rc, Weak};

use super::numpy::Dtype;
use super::{ArrayData, NdArray, PickleError, Value};

/// Deepest nesting accepted in a decoded value; Python itself cannot pickle much deeper
/// (recursion limit 1000), and it bounds the recursion of conversion, `Drop` and `PartialEq`.
pub(crate) const MAX_DEPTH: usize = 1000;

/// A stack / memo slot. Immutable scalars are stored inline, everything else behind `Shared`.
// No Debug: a recursive value would print forever.
#[derive(Clone)]
pub(crate) enum Item {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(Rc<str>),
    Bytes(Rc<[u8]>),
    Ref(Shared),
}

thread_local! {
    /// Every container of the unpickle running on this thread (see [`CycleBreaker`]).
    static CREATED: RefCell<Vec<Weak<RefCell<Obj>>>> = const { RefCell::new(Vec::new()) };
}

/// Frees what reference cycles would keep alive: a malformed (or hostile) pickle can put a
/// container inside itself through the memo, and `Rc` never frees a cycle. Once an unpickle is
/// over — its result converted to an owned [`Value`], or an error — every container it made is
/// emptied when this guard drops.
pub(crate) struct CycleBreaker(());

impl CycleBreaker {
    pub fn start() -> Self {
        CREATED.with(|c| c.borrow_mut().clear());
        Self(())
    }
}

impl Drop for CycleBreaker {
    fn drop(&mut self) {
        let created = CREATED.with(|c| std::mem::take(&mut *c.borrow_mut()));
        let mut children = Vec::new();
        for weak in created {
            if let Some(rc) = weak.upgrade() {
                if let Ok(mut obj) = rc.try_borrow_mut() {
                    obj.take_children(&mut children);
                }
            }
        }
        drop(children);
    }
}

impl Item {
    pub fn new(obj: Obj) -> Self {
        let rc = Rc::new(RefCell::new(obj));
        CREATED.with(|c| c.borrow_mut().push(Rc::downgrade(&rc)));
        Item::Ref(Shared(rc))
    }

    pub fn str(s: &str) -> Self {
        Item::Str(Rc::from(s))
    }

    pub fn bytes(b: &[u8]) -> Self {
        Item::Bytes(Rc::from(b))
    }

    /// Item for a scalar value (numpy scalars); containers go through `Obj`.
    pub fn from_scalar(v: Value) -> Self {
        match v {
            Value::None => Item::None,
            Value::Bool(b) => Item::Bool(b),
            Value::Int(i) => Item::Int(i),
            Value::Float(f) => Item::Float(f),
            Value::Str(s) => Item::str(&s),
            Value::Bytes(b) => Item::bytes(&b),
            Value::Array(a) => Item::new(Obj::Array(a)),
            other => Item::new(Obj::Global(other.type_name())),
        }
    }

    /// Short description for error messages.
    pub fn kind(&self) -> String {
        match self {
            Item::None => "None".into(),
            Item::Bool(_) => "bool".into(),
            Item::Int(_) => "int".into(),
            Item::Float(_) => "float".into(),
            Item::Str(_) => "str".into(),
            Item::Bytes(_) => "bytes".into(),
            Item::Ref(s) => match s.0.try_borrow() {
                Ok(obj) => obj.kind(),
                Err(_) => "object".into(),
            },
        }
    }
}

/// A shared, mutable container whose `Drop` is iterative, so that deeply nested input
/// cannot overflow the stack while being freed.
#[derive(Clone)]
pub(crate) struct Shared(pub Rc<RefCell<Obj>>);

impl Drop for Shared {
    fn drop(&mut self) {
        if Rc::strong_count(&self.0) != 1 {
            return;
        }
        let mut work = Vec::new();
        if let Ok(mut obj) = self.0.try_borrow_mut() {
            obj.take_children(&mut work);
        }
        while let Some(child) = work.pop() {
            if Rc::strong_count(&child.0) == 1 {
                if let Ok(mut obj) = child.0.try_borrow_mut() {
                    obj.take_children(&mut work);
                }
            }
            // `child` now has no shared children: its own drop does no recursion.
        }
    }
}

#[derive(Clone, Default)]
pub(crate) enum Obj {
    /// What is left after the contents were moved out.
    #[default]
    Empty,
    List(Vec<Item>),
    Tuple(Vec<Item>),
    Dict(Entries),
    /// A set: keys of the entries, values unused.
    Set(Entries),
    Global(String),
    Object {
        class: String,
        args: Vec<Item>,
        state: Option<Item>,
    },
    Dtype(Dtype),
    /// `numpy.core.multiarray._reconstruct(ndarray, ...)`, waiting for BUILD.
    PendingArray,
    Array(NdArray),
    ObjectArray {
        shape: Vec<usize>,
        items: Vec<Item>,
    },
}

impl Obj {
    pub fn kind(&self) -> String {
        match self {
            Obj::Empty => "object".into(),
            Obj::List(_) => "list".into(),
            Obj::Tuple(_) => "tuple".into(),
            Obj::Dict(_) => "dict".into(),
            Obj::Set(_) => "set".into(),
            Obj::Global(name) => format!("global {name}"),
            Obj::Object { class, .. } => format!("{class} object"),
            Obj::Dtype(_) => "numpy.dtype".into(),
            Obj::PendingArray | Obj::Array(_) | Obj::ObjectArray { .. } => "numpy.ndarray".into(),
        }
    }

    /// APPEND / APPENDS.
    pub fn append(&mut self, items: Vec<Item>) -> Result<(), String> {
        // Instances of list subclasses get their items appended: keep them as a list.
        if let Obj::Object { .. } = self {
            *self = Obj::List(Vec::new());
        }
        match self {
            Obj::List(list) => {
                list.extend(items);
                Ok(())
            }
            other => Err(format!("cannot append to {}", other.kind())),
        }
    }

    /// SETITEM / SETITEMS with alternating keys and values.
    pub fn set_items(&mut self, items: Vec<Item>) -> Result<(), String> {
        // Instances of dict subclasses (OrderedDict, EasyDict...) decode as plain dicts.
        if let Obj::Object { .. } = self {
            *self = Obj::Dict(Entries::default());
        }
        match self {
            Obj::Dict(entries) => {
                let mut it = items.into_iter();
                while let (Some(k), Some(v)) = (it.next(), it.next()) {
                    entries.insert(k, v);
                }
                Ok(())
            }
            other => Err(format!("cannot set items on {}", other.kind())),
        }
    }

    fn take_children(&mut self, out: &mut Vec<Shared>) {
        let mut push = |items: Vec<Item>| {
            out.extend(items.into_iter().filter_map(|i| match i {
                Item::Ref(s) => Some(s),
                _ => None,
            }))
        };
        match self {
            Obj::List(v) | Obj::Tuple(v) | Obj::ObjectArray { items: v, .. } => push(std::mem::take(v)),
            Obj::Dict(e) | Obj::Set(e) => {
                e.index.clear();
                for (k, v) in std::mem::take(&mut e.pairs) {
                    push(vec![k, v]);
                }
            }
            Obj::Object { args, state, .. } => {
                push(std::mem::take(args));
                push(state.take().into_iter().collect());
            }
            _ => {}
        }
    }
}

/// Hashable form of scalar keys, so that SETITEM on an existing key replaces it like Python.
/// `True == 1 == 1.0` in Python, hence the numeric folding.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) enum Key {
    None,
    Int(i64),
    FloatBits(u64),
    Str(Rc<str>),
    Bytes(Rc<[u8]>),
}

impl Key {
    fn of(item: &Item) -> Option<Key> {
        Some(match item {
            Item::None => Key::None,
            Item::Bool(b) => Key::Int(i64::from(*b)),
            Item::Int(i) => Key::Int(*i),
            Item::Float(f) if f.fract() == 0.0 && f.abs() < 9.0e18 => Key::Int(*f as i64),
            Item::Float(f) if !f.is_nan() => Key::FloatBits(f.to_bits()),
            Item::Str(s) => Key::Str(s.clone()),
            Item::Bytes(b) => Key::Bytes(b.clone()),
            _ => return None,
        })
    }
}

/// Insertion-ordered dict entries with Python's replace-on-duplicate-key semantics.
#[derive(Clone, Default)]
pub(crate) struct Entries {
    pub pairs: Vec<(Item, Item)>,
    index: HashMap<Key, usize>,
}

impl Entries {
    pub fn insert(&mut self, key: Item, value: Item) {
        if let Some(k) = Key::of(&key) {
            if let Some(&i) = self.index.get(&k) {
                self.pairs[i].1 = value;
                return;
            }
            self.index.insert(k, self.pairs.len());
        }
        self.pairs.push((key, value));
    }
}

/// Converts the final stack item to an owned tree.
/// `offset` (of STOP) is what errors report.
pub(crate) fn into_value(root: Item, input_len: usize, offset: usize) -> Result<Value, PickleError> {
    let mut cx = Convert {
        offset,
        in_progress: HashSet::new(),
        // Shared sub-trees are copied once per reference; bound the total so that a small
        // pickle of nested shared references cannot expand exponentially.
        budget: input_len.saturating_mul(64).saturating_add(1_000_000),
    };
    cx.item(root, 0)
}

struct Convert {
    offset: usize,
    in_progress: HashSet<*const RefCell<Obj>>,
    budget: usize,
}

impl Convert {
    fn err(&self, msg: &str) -> PickleError {
        PickleError::invalid(self.offset, msg)
    }

    fn spend(&mut self, n: usize) -> Result<(), PickleError> {
        match self.budget.checked_sub(n) {
            Some(left) => self.budget = left,
            None => return Err(self.err("shared references expand to a value too large to build")),
        }
        Ok(())
    }

    fn item(&mut self, item: Item, depth: usize) -> Result<Value, PickleError> {
        self.spend(1)?;
        Ok(match item {
            Item::None => Value::None,
            Item::Bool(b) => Value::Bool(b),
            Item::Int(i) => Value::Int(i),
            Item::Float(f) => Value::Float(f),
            Item::Str(s) => Value::Str(s.to_string()),
            Item::Bytes(b) => Value::Bytes(b.to_vec()),
            Item::Ref(shared) => {
                if depth >= MAX_DEPTH {
                    return Err(self.err("value nested deeper than 1000 levels"));
                }
                if Rc::strong_count(&shared.0) == 1 {
                    // Sole owner: move the contents out instead of copying them.
                    let obj = std::mem::take(&mut *shared.0.borrow_mut());
                    self.obj(obj, depth)?
                } else {
                    let ptr = Rc::as_ptr(&shared.0);
                    if !self.in_progress.insert(ptr) {
                        return Err(self.err("recursive (self-referencing) values are not supported"));
                    }
                    let obj = shared.0.borrow().clone();
                    if let Obj::Array(a) = &obj {
                        self.spend(a.len())?;
                    }
                    let value = self.obj(obj, depth);
                    self.in_progress.remove(&ptr);
                    value?
                }
            }
        })
    }

    fn items(&mut self, items: Vec<Item>, depth: usize) -> Result<Vec<Value>, PickleError> {
        items.into_iter().map(|i| self.item(i, depth + 1)).collect()
    }

    fn obj(&mut self, obj: Obj, depth: usize) -> Result<Value, PickleError> {
        Ok(match obj {
            Obj::Empty => Value::None,
            Obj::List(v) => Value::List(self.items(v, depth)?),
            Obj::Tuple(v) => Value::Tuple(self.items(v, depth)?),
            Obj::Set(e) => Value::Set(self.items(e.pairs.into_iter().map(|(k, _)| k).collect(), depth)?),
            Obj::Dict(e) => Value::Dict(
                e.pairs
                    .into_iter()
                    .map(|(k, v)| Ok((self.item(k, depth + 1)?, self.item(v, depth + 1)?)))
                    .collect::<Result<_, PickleError>>()?,
            ),
            Obj::Global(name) => Value::Global(name),
            Obj::Object { class, args, state } => Value::Object {
                class,
                args: self.items(args, depth)?,
                state: match state {
                    Some(s) => Some(Box::new(self.item(s, depth + 1)?)),
                    None => None,
                },
            },
            Obj::Dtype(d) => {
                Value::Object { class: "numpy.dtype".into(), args: vec![Value::Str(d.display())], state: None }
            }
            Obj::PendingArray => Value::Object { class: "numpy.ndarray".into(), args: Vec::new(), state: None },
            Obj::Array(a) => Value::Array(a),
            Obj::ObjectArray { shape, items } => {
                Value::Array(NdArray { shape, data: ArrayData::Object(self.items(items, depth)?) })
            }
        })
    }
}
