//! The queue between the source and inference. A live sensor does not wait: when inference
//! falls behind, the oldest pending sweep is dropped (and counted), so memory stays bounded and
//! latency does not grow. Recorded sources that may wait use [`DropOldestQueue::push_wait`].

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex};

struct State<T> {
    items: VecDeque<T>,
    closed: bool,
    dropped: u64,
}

pub struct DropOldestQueue<T> {
    capacity: usize,
    state: Mutex<State<T>>,
    changed: Condvar,
}

impl<T> DropOldestQueue<T> {
    /// A queue holding at most `capacity` (≥ 1) items.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            state: Mutex::new(State { items: VecDeque::new(), closed: false, dropped: 0 }),
            changed: Condvar::new(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State<T>> {
        // A panic elsewhere must not take the queue down with it: the state stays consistent.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Adds `item`; when full, the oldest item is dropped first. Returns whether one was.
    pub fn push(&self, item: T) -> bool {
        let mut s = self.lock();
        let dropped = s.items.len() >= self.capacity;
        if dropped {
            s.items.pop_front();
            s.dropped += 1;
        }
        s.items.push_back(item);
        drop(s);
        self.changed.notify_all();
        dropped
    }

    /// Adds `item`, waiting while the queue is full (lossless, for recorded sources). Returns
    /// `false` (item not added) when the queue was closed meanwhile.
    pub fn push_wait(&self, item: T) -> bool {
        let mut s = self.lock();
        while s.items.len() >= self.capacity && !s.closed {
            s = self.changed.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        if s.closed {
            return false;
        }
        s.items.push_back(item);
        drop(s);
        self.changed.notify_all();
        true
    }

    /// The oldest item, waiting for one; `None` once the queue is closed and empty.
    pub fn pop(&self) -> Option<T> {
        let mut s = self.lock();
        loop {
            if let Some(item) = s.items.pop_front() {
                drop(s);
                self.changed.notify_all();
                return Some(item);
            }
            if s.closed {
                return None;
            }
            s = self.changed.wait(s).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// No more items will come: [`pop`](Self::pop) drains what is left, then returns `None`.
    pub fn close(&self) {
        self.lock().closed = true;
        self.changed.notify_all();
    }

    pub fn is_closed(&self) -> bool {
        self.lock().closed
    }

    /// Items dropped so far because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }

    pub fn len(&self) -> usize {
        self.lock().items.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn full_queue_drops_the_oldest() {
        let q = DropOldestQueue::new(2);
        assert!(!q.push(1));
        assert!(!q.push(2));
        assert!(q.push(3));
        assert_eq!(q.dropped(), 1);
        q.close();
        assert_eq!((q.pop(), q.pop(), q.pop()), (Some(2), Some(3), None));
    }

    #[test]
    fn push_wait_blocks_until_there_is_room_and_loses_nothing() {
        let q = Arc::new(DropOldestQueue::new(1));
        let producer = {
            let q = q.clone();
            std::thread::spawn(move || {
                for i in 0..100 {
                    assert!(q.push_wait(i));
                }
                q.close();
            })
        };
        let got: Vec<i32> = std::iter::from_fn(|| q.pop()).collect();
        producer.join().unwrap();
        assert_eq!(got, (0..100).collect::<Vec<_>>());
        assert_eq!(q.dropped(), 0);
    }

    #[test]
    fn closing_wakes_a_waiting_producer() {
        let q = Arc::new(DropOldestQueue::new(1));
        q.push(0);
        let producer = {
            let q = q.clone();
            std::thread::spawn(move || q.push_wait(1))
        };
        std::thread::sleep(std::time::Duration::from_millis(20));
        q.close();
        assert!(!producer.join().unwrap());
    }
}
