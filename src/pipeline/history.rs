//! Double-buffered filter state: read the previous frame's planes, write the next, swap.

use crate::frame::Plane;

/// `N` planes of history, double-buffered so no pixel reads what another pixel of the same
/// frame writes (the CPU and GPU backends compute the same function).
#[derive(Clone, Debug)]
pub struct DoubleBuffer {
    planes: usize,
    read: Vec<Plane<f32>>,
    write: Vec<Plane<f32>>,
    valid: bool,
}

impl DoubleBuffer {
    /// State of `planes` planes; nothing allocated until the first frame.
    pub fn new(planes: usize) -> Self {
        DoubleBuffer {
            planes,
            read: Vec::new(),
            write: Vec::new(),
            valid: false,
        }
    }

    /// The size of the allocated planes, if any.
    pub fn size(&self) -> Option<(usize, usize)> {
        self.read.first().map(Plane::size)
    }

    /// Makes sure both buffers are `width` x `height`; reallocating drops the history.
    pub fn ensure(&mut self, width: usize, height: usize) {
        if self.size() != Some((width, height)) {
            self.read = (0..self.planes).map(|_| Plane::new(width, height)).collect();
            self.write = (0..self.planes).map(|_| Plane::new(width, height)).collect();
            self.valid = false;
        }
    }

    /// Whether the read side holds a previous frame.
    pub fn valid(&self) -> bool {
        self.valid
    }

    /// The previous frame's planes (meaningful only when [`Self::valid`]) and the planes to
    /// write this frame into.
    pub fn split(&mut self) -> (&[Plane<f32>], &mut [Plane<f32>]) {
        (&self.read, &mut self.write)
    }

    /// The previous frame's planes.
    pub fn read(&self) -> &[Plane<f32>] {
        &self.read
    }

    /// The previous frame's planes, mutable (to change the space they are stored in).
    pub fn read_mut(&mut self) -> &mut [Plane<f32>] {
        &mut self.read
    }

    /// After a frame: what was written becomes the history.
    pub fn swap(&mut self) {
        std::mem::swap(&mut self.read, &mut self.write);
        self.valid = true;
    }

    /// Forgets the history (keeps the allocation).
    pub fn reset(&mut self) {
        self.valid = false;
    }

    /// Drops the history and its memory.
    pub fn release(&mut self) {
        self.read.clear();
        self.write.clear();
        self.valid = false;
    }

    /// Bytes held by both buffers.
    pub fn bytes(&self) -> usize {
        (self.read.len() + self.write.len()) * self.size().map_or(0, |(w, h)| w * h) * 4
    }
}
