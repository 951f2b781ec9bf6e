//! The unpickling virtual machine (protocols 0–5), following CPython's `Lib/pickle.py`.

use std::collections::HashMap;

use super::objects::{into_value, CycleBreaker, Entries, Item, Obj};
use super::opcodes as op;
use super::text::{self, IntError};
use super::{PickleError, Value};

/// Decodes a whole pickle (up to its STOP opcode).
pub(crate) fn unpickle(data: &[u8]) -> Result<Value, PickleError> {
    let _cycles = CycleBreaker::start();
    let mut vm =
        Unpickler { data, pos: 0, op_start: 0, stack: Vec::new(), metastack: Vec::new(), memo: HashMap::new() };
    let root = vm.run()?;
    let stop = vm.op_start;
    // Free the memo first so that most containers are uniquely owned and get moved, not copied.
    drop(vm);
    into_value(root, data.len(), stop)
}

pub(crate) struct Unpickler<'a> {
    data: &'a [u8],
    pos: usize,
    /// Offset of the opcode being executed, for error messages.
    pub(crate) op_start: usize,
    stack: Vec<Item>,
    /// Stacks saved by MARK (the same model as CPython's `metastack`).
    metastack: Vec<Vec<Item>>,
    memo: HashMap<u64, Item>,
}

impl<'a> Unpickler<'a> {
    pub(crate) fn err(&self, message: impl Into<String>) -> PickleError {
        PickleError::invalid(self.op_start, message)
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], PickleError> {
        let available = self.data.len() - self.pos;
        if n > available {
            return Err(PickleError::Truncated { needed: n, offset: self.pos, available });
        }
        let out = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], PickleError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.take(N)?);
        Ok(out)
    }

    fn u8(&mut self) -> Result<u8, PickleError> {
        Ok(self.array::<1>()?[0])
    }

    fn u32(&mut self) -> Result<u32, PickleError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    fn u64(&mut self) -> Result<u64, PickleError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    /// A length prefix, checked against what is left before anything is allocated.
    fn len_u64(&mut self, n: u64) -> Result<&'a [u8], PickleError> {
        let n = usize::try_from(n).unwrap_or(usize::MAX);
        self.take(n)
    }

    fn len_i32(&mut self) -> Result<&'a [u8], PickleError> {
        let n = i32::from_le_bytes(self.array()?);
        let n = u64::try_from(n).map_err(|_| self.err("negative length"))?;
        self.len_u64(n)
    }

    /// A newline-terminated argument, without the newline.
    fn line(&mut self) -> Result<&'a [u8], PickleError> {
        let rest = &self.data[self.pos..];
        match rest.iter().position(|&b| b == b'\n') {
            Some(i) => {
                self.pos += i + 1;
                Ok(&rest[..i])
            }
            None => Err(PickleError::Truncated { needed: rest.len() + 1, offset: self.pos, available: rest.len() }),
        }
    }

    fn utf8_line(&mut self) -> Result<&'a str, PickleError> {
        let line = self.line()?;
        std::str::from_utf8(line).map_err(|_| self.err("argument is not UTF-8"))
    }

    fn push(&mut self, item: Item) {
        self.stack.push(item);
    }

    fn pop(&mut self) -> Result<Item, PickleError> {
        self.stack.pop().ok_or_else(|| self.err("stack underflow"))
    }

    fn top(&self) -> Result<&Item, PickleError> {
        self.stack.last().ok_or_else(|| self.err("stack underflow"))
    }

    fn pop_mark(&mut self) -> Result<Vec<Item>, PickleError> {
        let saved = self.metastack.pop().ok_or_else(|| self.err("no MARK on the stack"))?;
        Ok(std::mem::replace(&mut self.stack, saved))
    }

    fn pop_n(&mut self, n: usize) -> Result<Vec<Item>, PickleError> {
        if self.stack.len() < n {
            return Err(self.err("stack underflow"));
        }
        Ok(self.stack.split_off(self.stack.len() - n))
    }

    fn int_line(&mut self) -> Result<i64, PickleError> {
        let line = self.line()?;
        self.parse_int(line)
    }

    fn parse_int(&self, line: &[u8]) -> Result<i64, PickleError> {
        text::parse_int(line).map_err(|e| match e {
            IntError::Overflow => PickleError::IntOverflow { offset: self.op_start },
            IntError::Invalid => self.err("invalid integer literal"),
        })
    }

    fn long(&self, bytes: &[u8]) -> Result<Item, PickleError> {
        text::decode_long(bytes).map(Item::Int).ok_or(PickleError::IntOverflow { offset: self.op_start })
    }

    fn memo_get(&self, key: u64) -> Result<Item, PickleError> {
        self.memo.get(&key).cloned().ok_or_else(|| self.err(format!("memo key {key} was never stored")))
    }

    fn memo_put(&mut self, key: u64) -> Result<(), PickleError> {
        let top = self.top()?.clone();
        self.memo.insert(key, top);
        Ok(())
    }

    /// Runs the given closure on the container at the top of the stack.
    fn with_top<R>(&self, f: impl FnOnce(&mut Obj) -> Result<R, String>) -> Result<R, PickleError> {
        match self.top()? {
            Item::Ref(shared) => {
                let mut obj = shared.0.try_borrow_mut().map_err(|_| self.err("object is already borrowed"))?;
                f(&mut obj).map_err(|m| self.err(m))
            }
            other => Err(self.err(format!("expected a container, found {}", other.kind()))),
        }
    }

    fn append(&mut self, items: Vec<Item>) -> Result<(), PickleError> {
        self.with_top(|obj| obj.append(items))
    }

    fn set_items(&mut self, items: Vec<Item>) -> Result<(), PickleError> {
        if !items.len().is_multiple_of(2) {
            return Err(self.err("odd number of items for a dict"));
        }
        self.with_top(|obj| obj.set_items(items))
    }

    fn str_or_bytes(bytes: &[u8]) -> Item {
        match std::str::from_utf8(bytes) {
            Ok(s) => Item::str(s),
            Err(_) => Item::bytes(bytes),
        }
    }

    fn unicode(bytes: &[u8]) -> Item {
        // Python writes lone surrogates with 'surrogatepass'; Rust strings cannot hold them.
        Item::str(&String::from_utf8_lossy(bytes))
    }

    fn global(&self, module: &str, name: &str) -> Item {
        // Python 2 names, as CPython's fix_imports maps them.
        let module = match module {
            "__builtin__" => "builtins",
            "copy_reg" => "copyreg",
            other => other,
        };
        Item::new(Obj::Global(format!("{module}.{name}")))
    }

    fn run(&mut self) -> Result<Item, PickleError> {
        loop {
            self.op_start = self.pos;
            let code = self.u8()?;
            match code {
                op::PROTO => {
                    if self.u8()? > 5 {
                        return Err(self.err("unsupported pickle protocol"));
                    }
                }
                op::FRAME => {
                    self.u64()?;
                }
                op::STOP => return self.pop(),
                op::MARK => {
                    let stack = std::mem::take(&mut self.stack);
                    self.metastack.push(stack);
                }
                op::POP => {
                    if self.stack.pop().is_none() {
                        self.pop_mark()?;
                    }
                }
                op::POP_MARK => {
                    self.pop_mark()?;
                }
                op::DUP => {
                    let top = self.top()?.clone();
                    self.push(top);
                }
                op::NONE => self.push(Item::None),
                op::NEWTRUE => self.push(Item::Bool(true)),
                op::NEWFALSE => self.push(Item::Bool(false)),
                op::INT => {
                    let line = self.line()?;
                    // Protocol 0 spells booleans as INT 01 / 00.
                    let item = match line {
                        b"01" => Item::Bool(true),
                        b"00" => Item::Bool(false),
                        _ => Item::Int(self.parse_int(line)?),
                    };
                    self.push(item);
                }
                op::LONG => {
                    let v = self.int_line()?;
                    self.push(Item::Int(v));
                }
                op::BININT => {
                    let v = i32::from_le_bytes(self.array()?);
                    self.push(Item::Int(v.into()));
                }
                op::BININT1 => {
                    let v = self.u8()?;
                    self.push(Item::Int(v.into()));
                }
                op::BININT2 => {
                    let v = u16::from_le_bytes(self.array()?);
                    self.push(Item::Int(v.into()));
                }
                op::LONG1 => {
                    let n = self.u8()?;
                    let bytes = self.take(n.into())?;
                    let item = self.long(bytes)?;
                    self.push(item);
                }
                op::LONG4 => {
                    let bytes = self.len_i32()?;
                    let item = self.long(bytes)?;
                    self.push(item);
                }
                op::FLOAT => {
                    let line = self.line()?;
                    let v = text::parse_float(line).ok_or_else(|| self.err("invalid float"))?;
                    self.push(Item::Float(v));
                }
                op::BINFLOAT => {
                    let v = f64::from_be_bytes(self.array()?);
                    self.push(Item::Float(v));
                }
                op::STRING => {
                    let line = self.line()?;
                    let bytes = text::unescape_string(line)
                        .ok_or_else(|| self.err("STRING argument must be a quoted literal"))?;
                    self.push(Self::str_or_bytes(&bytes));
                }
                op::BINSTRING => {
                    let bytes = self.len_i32()?;
                    self.push(Self::str_or_bytes(bytes));
                }
                op::SHORT_BINSTRING => {
                    let n = self.u8()?;
                    let bytes = self.take(n.into())?;
                    self.push(Self::str_or_bytes(bytes));
                }
                op::UNICODE => {
                    let line = self.line()?;
                    let s =
                        text::raw_unicode_escape(line).ok_or_else(|| self.err("invalid raw-unicode-escape string"))?;
                    self.push(Item::str(&s));
                }
                op::BINUNICODE => {
                    let n = self.u32()?;
                    let bytes = self.len_u64(n.into())?;
                    self.push(Self::unicode(bytes));
                }
                op::SHORT_BINUNICODE => {
                    let n = self.u8()?;
                    let bytes = self.take(n.into())?;
                    self.push(Self::unicode(bytes));
                }
                op::BINUNICODE8 => {
                    let n = self.u64()?;
                    let bytes = self.len_u64(n)?;
                    self.push(Self::unicode(bytes));
                }
                op::BINBYTES => {
                    let n = self.u32()?;
                    let bytes = self.len_u64(n.into())?;
                    self.push(Item::bytes(bytes));
                }
                op::SHORT_BINBYTES => {
                    let n = self.u8()?;
                    let bytes = self.take(n.into())?;
                    self.push(Item::bytes(bytes));
                }
                op::BINBYTES8 | op::BYTEARRAY8 => {
                    let n = self.u64()?;
                    let bytes = self.len_u64(n)?;
                    self.push(Item::bytes(bytes));
                }
                op::EMPTY_LIST => self.push(Item::new(Obj::List(Vec::new()))),
                op::EMPTY_TUPLE => self.push(Item::new(Obj::Tuple(Vec::new()))),
                op::EMPTY_DICT => self.push(Item::new(Obj::Dict(Entries::default()))),
                op::EMPTY_SET => self.push(Item::new(Obj::Set(Entries::default()))),
                op::APPEND => {
                    let v = self.pop()?;
                    self.append(vec![v])?;
                }
                op::APPENDS => {
                    let items = self.pop_mark()?;
                    self.append(items)?;
                }
                op::LIST => {
                    let items = self.pop_mark()?;
                    self.push(Item::new(Obj::List(items)));
                }
                op::TUPLE => {
                    let items = self.pop_mark()?;
                    self.push(Item::new(Obj::Tuple(items)));
                }
                op::TUPLE1 | op::TUPLE2 | op::TUPLE3 => {
                    let items = self.pop_n(usize::from(code - op::TUPLE1) + 1)?;
                    self.push(Item::new(Obj::Tuple(items)));
                }
                op::DICT => {
                    let items = self.pop_mark()?;
                    self.push(Item::new(Obj::Dict(Entries::default())));
                    self.set_items(items)?;
                }
                op::SETITEM => {
                    let items = self.pop_n(2)?;
                    self.set_items(items)?;
                }
                op::SETITEMS => {
                    let items = self.pop_mark()?;
                    self.set_items(items)?;
                }
                op::ADDITEMS => {
                    let items = self.pop_mark()?;
                    self.with_top(|obj| match obj {
                        Obj::Set(set) => {
                            items.into_iter().for_each(|k| set.insert(k, Item::None));
                            Ok(())
                        }
                        other => Err(format!("cannot add items to {}", other.kind())),
                    })?;
                }
                op::FROZENSET => {
                    let mut set = Entries::default();
                    self.pop_mark()?.into_iter().for_each(|k| set.insert(k, Item::None));
                    self.push(Item::new(Obj::Set(set)));
                }
                op::GET => {
                    let key = self.int_line()?;
                    let item = self.memo_get(key as u64)?;
                    self.push(item);
                }
                op::BINGET => {
                    let key = self.u8()?;
                    let item = self.memo_get(key.into())?;
                    self.push(item);
                }
                op::LONG_BINGET => {
                    let key = self.u32()?;
                    let item = self.memo_get(key.into())?;
                    self.push(item);
                }
                op::PUT => {
                    let key = self.int_line()?;
                    self.memo_put(key as u64)?;
                }
                op::BINPUT => {
                    let key = self.u8()?;
                    self.memo_put(key.into())?;
                }
                op::LONG_BINPUT => {
                    let key = self.u32()?;
                    self.memo_put(key.into())?;
                }
                op::MEMOIZE => {
                    let key = self.memo.len() as u64;
                    self.memo_put(key)?;
                }
                op::GLOBAL => {
                    let module = self.utf8_line()?;
                    let name = self.utf8_line()?;
                    let item = self.global(module, name);
                    self.push(item);
                }
                op::STACK_GLOBAL => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    let item = match (&module, &name) {
                        (Item::Str(m), Item::Str(n)) => self.global(m, n),
                        _ => return Err(self.err("STACK_GLOBAL needs two strings")),
                    };
                    self.push(item);
                }
                op::REDUCE => {
                    let args = self.pop()?;
                    let callable = self.pop()?;
                    let args = self.tuple_items(&args)?;
                    let item = self.reduce(&callable, args)?;
                    self.push(item);
                }
                op::BUILD => {
                    let state = self.pop()?;
                    let target = self.top()?.clone();
                    self.build(&target, state)?;
                }
                op::NEWOBJ => {
                    let args = self.pop()?;
                    let class = self.pop()?;
                    let args = self.tuple_items(&args)?;
                    let item = self.new_object(&class, args)?;
                    self.push(item);
                }
                op::NEWOBJ_EX => {
                    let kwargs = self.pop()?;
                    let args = self.pop()?;
                    let class = self.pop()?;
                    let mut args = self.tuple_items(&args)?;
                    let has_kwargs = match &kwargs {
                        Item::Ref(s) => !matches!(
                            s.0.try_borrow().as_deref(),
                            Ok(Obj::Dict(d)) if d.pairs.is_empty()
                        ),
                        _ => true,
                    };
                    if has_kwargs {
                        args.push(kwargs);
                    }
                    let item = self.new_object(&class, args)?;
                    self.push(item);
                }
                op::INST => {
                    let module = self.utf8_line()?;
                    let name = self.utf8_line()?;
                    let class = self.global(module, name);
                    let args = self.pop_mark()?;
                    let item = self.reduce(&class, args)?;
                    self.push(item);
                }
                op::OBJ => {
                    let mut args = self.pop_mark()?;
                    if args.is_empty() {
                        return Err(self.err("OBJ without a class"));
                    }
                    let class = args.remove(0);
                    let item = self.reduce(&class, args)?;
                    self.push(item);
                }
                _ => {
                    return Err(PickleError::UnsupportedOpcode {
                        opcode: code,
                        name: op::name(code),
                        offset: self.op_start,
                    })
                }
            }
        }
    }

    pub(crate) fn tuple_items(&self, item: &Item) -> Result<Vec<Item>, PickleError> {
        if let Item::Ref(s) = item {
            if let Ok(Obj::Tuple(items)) = s.0.try_borrow().as_deref() {
                return Ok(items.clone());
            }
        }
        Err(self.err(format!("expected an argument tuple, found {}", item.kind())))
    }
}
