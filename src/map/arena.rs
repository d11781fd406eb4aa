//! Fixed-capacity arena with generational handles: slots allocated once, freed slots recycled,
//! stale handles detected by their generation (no raw pointers, no `Rc` cycles). A full arena
//! refuses inserts; the owner culls, it never grows.

use std::marker::PhantomData;

/// A handle to a value of type `T` in an [`Arena`].
pub struct Handle<T> {
    index: u32,
    generation: u32,
    _t: PhantomData<fn() -> T>,
}

impl<T> Handle<T> {
    pub fn index(&self) -> usize {
        self.index as usize
    }
    pub fn generation(&self) -> u32 {
        self.generation
    }
}

// Manual impls: derive would require T: Clone/Eq/...
impl<T> Clone for Handle<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Handle<T> {}
impl<T> PartialEq for Handle<T> {
    fn eq(&self, o: &Self) -> bool {
        self.index == o.index && self.generation == o.generation
    }
}
impl<T> Eq for Handle<T> {}
impl<T> std::hash::Hash for Handle<T> {
    fn hash<H: std::hash::Hasher>(&self, h: &mut H) {
        (self.index, self.generation).hash(h)
    }
}
impl<T> PartialOrd for Handle<T> {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl<T> Ord for Handle<T> {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        (self.index, self.generation).cmp(&(o.index, o.generation))
    }
}
impl<T> std::fmt::Debug for Handle<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "#{}v{}", self.index, self.generation)
    }
}

struct Slot<T> {
    generation: u32,
    value: Option<T>,
}

/// The arena is full: cull before inserting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("arena full ({capacity} slots)")]
pub struct ArenaFull {
    pub capacity: usize,
}

pub struct Arena<T> {
    /// Slots used so far, in a buffer reserved for `capacity` (never reallocated): a slot is
    /// first written when first needed, so the untouched rest of a large arena (100,000 map
    /// points) costs address space, not resident memory.
    slots: Vec<Slot<T>>,
    /// Freed slots, reused (last freed first) before a new one is taken.
    free: Vec<u32>,
    capacity: usize,
    len: usize,
}

impl<T> Arena<T> {
    /// Allocates `capacity` slots up front (capped at `u32::MAX`, the handles' range).
    pub fn with_capacity(capacity: usize) -> Self {
        let capacity = capacity.min(u32::MAX as usize);
        Arena {
            slots: Vec::with_capacity(capacity),
            free: Vec::with_capacity(capacity),
            capacity,
            len: 0,
        }
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }
    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    pub fn is_full(&self) -> bool {
        self.free.is_empty() && self.slots.len() == self.capacity
    }

    /// Stores `value`, or gives it back with [`ArenaFull`].
    pub fn insert(&mut self, value: T) -> Result<Handle<T>, (ArenaFull, T)> {
        let i = match self.free.pop() {
            Some(i) => i,
            None if self.slots.len() < self.capacity => {
                // Within the reserved buffer: no reallocation.
                self.slots.push(Slot {
                    generation: 0,
                    value: None,
                });
                (self.slots.len() - 1) as u32
            }
            None => {
                return Err((
                    ArenaFull {
                        capacity: self.capacity,
                    },
                    value,
                ))
            }
        };
        let s = &mut self.slots[i as usize];
        s.value = Some(value);
        self.len += 1;
        Ok(Handle {
            index: i,
            generation: s.generation,
            _t: PhantomData,
        })
    }

    /// Removes the value; its handle (and copies of it) become stale.
    pub fn remove(&mut self, h: Handle<T>) -> Option<T> {
        let s = self.slots.get_mut(h.index as usize)?;
        if s.generation != h.generation {
            return None;
        }
        let v = s.value.take()?;
        s.generation = s.generation.wrapping_add(1);
        self.free.push(h.index);
        self.len -= 1;
        Some(v)
    }

    pub fn get(&self, h: Handle<T>) -> Option<&T> {
        let s = self.slots.get(h.index as usize)?;
        if s.generation == h.generation {
            s.value.as_ref()
        } else {
            None
        }
    }

    pub fn get_mut(&mut self, h: Handle<T>) -> Option<&mut T> {
        let s = self.slots.get_mut(h.index as usize)?;
        if s.generation == h.generation {
            s.value.as_mut()
        } else {
            None
        }
    }

    pub fn contains(&self, h: Handle<T>) -> bool {
        self.get(h).is_some()
    }

    /// Live values with their handles, in slot order.
    pub fn iter(&self) -> impl Iterator<Item = (Handle<T>, &T)> {
        self.slots.iter().enumerate().filter_map(|(i, s)| {
            s.value.as_ref().map(|v| {
                (
                    Handle {
                        index: i as u32,
                        generation: s.generation,
                        _t: PhantomData,
                    },
                    v,
                )
            })
        })
    }

    pub fn handles(&self) -> impl Iterator<Item = Handle<T>> + '_ {
        self.iter().map(|(h, _)| h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn handles_go_stale_and_slots_are_recycled_without_growth() {
        let mut a: Arena<String> = Arena::with_capacity(2);
        let h1 = a.insert("a".into()).unwrap();
        let h2 = a.insert("b".into()).unwrap();
        assert!(a.is_full());
        let (e, v) = a.insert("c".into()).unwrap_err();
        assert_eq!((e.capacity, v.as_str()), (2, "c"));
        assert_eq!(a.remove(h1).as_deref(), Some("a"));
        assert!(a.get(h1).is_none(), "stale handle");
        let h3 = a.insert("d".into()).unwrap();
        assert_eq!(h3.index(), h1.index());
        assert_ne!(h3, h1);
        assert!(a.get(h1).is_none());
        assert_eq!(a.get(h3).map(|s| s.as_str()), Some("d"));
        assert_eq!(a.remove(h1), None);
        assert_eq!(a.len(), 2);
        assert_eq!(a.capacity(), 2);
        assert_eq!(a.iter().count(), 2);
        let _ = h2;
    }

    #[test]
    fn slots_are_taken_in_order_and_the_last_freed_is_reused_first() {
        let mut a: Arena<u32> = Arena::with_capacity(4);
        assert!(!a.is_full() && a.capacity() == 4);
        let hs: Vec<Handle<u32>> = (0..3).filter_map(|v| a.insert(v).ok()).collect();
        assert_eq!(hs.iter().map(|h| h.index()).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(a.remove(hs[0]), Some(0));
        assert_eq!(a.remove(hs[2]), Some(2));
        let order: Vec<usize> = (10..13)
            .filter_map(|v| a.insert(v).ok())
            .map(|h| h.index())
            .collect();
        assert_eq!(order, [2, 0, 3]);
        assert!(a.is_full());
        assert!(a.insert(99).is_err());
        assert_eq!(
            a.iter().map(|(_, v)| *v).collect::<Vec<_>>(),
            [11, 1, 10, 12]
        );
    }
}
