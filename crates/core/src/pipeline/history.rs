//! Double-buffered filter state: read the previous frame's planes, write the next, swap.

use crate::frame::Plane;

/// `N` planes of history, double-buffered so no pixel reads what another pixel of the same
/// frame writes (the CPU and GPU backends compute the same function). A plane may hold
/// several channels per pixel, interleaved (texels): plane `k` of a `w x h` frame is then
/// `components[k] * w` samples wide.
#[derive(Clone, Debug)]
pub struct DoubleBuffer {
    components: Vec<usize>,
    size: Option<(usize, usize)>,
    read: Vec<Plane<f32>>,
    write: Vec<Plane<f32>>,
    valid: bool,
}

impl DoubleBuffer {
    /// State of `planes` planes of one channel; nothing allocated until the first frame.
    pub fn new(planes: usize) -> Self {
        Self::with_components(&vec![1; planes])
    }

    /// State of one plane per entry of `components`, each with that many channels per
    /// pixel, interleaved.
    pub fn with_components(components: &[usize]) -> Self {
        DoubleBuffer {
            components: components.to_vec(),
            size: None,
            read: Vec::new(),
            write: Vec::new(),
            valid: false,
        }
    }

    /// The size in pixels of the allocated planes, if any.
    pub fn size(&self) -> Option<(usize, usize)> {
        self.size
    }

    /// Makes sure both buffers are `width` x `height` pixels; reallocating drops the history.
    pub fn ensure(&mut self, width: usize, height: usize) {
        if self.size != Some((width, height)) {
            let planes = || {
                self.components
                    .iter()
                    .map(|&c| Plane::new(c * width, height))
                    .collect()
            };
            self.read = planes();
            self.write = planes();
            self.size = Some((width, height));
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
        self.size = None;
        self.valid = false;
    }

    /// The channels per pixel of each plane.
    pub fn components(&self) -> &[usize] {
        &self.components
    }

    /// The size of the history, when there is one (its planes are [`Self::read`]).
    pub fn history_size(&self) -> Option<(usize, usize)> {
        self.size.filter(|_| self.valid)
    }

    /// Makes `planes`, a `size` (width, height) history laid out as [`Self::components`]
    /// says, the history. Planes of another layout are refused with what differs (and the
    /// buffer is left as it was).
    pub fn restore(&mut self, size: (usize, usize), planes: Vec<Plane<f32>>) -> Result<(), String> {
        let (w, h) = size;
        let expected: Vec<(usize, usize)> = self.components.iter().map(|&c| (c * w, h)).collect();
        let got: Vec<(usize, usize)> = planes.iter().map(Plane::size).collect();
        if expected != got {
            return Err(format!(
                "its planes are {got:?} samples, but a {w}x{h} history of this filter is {expected:?}"
            ));
        }
        self.ensure(w, h);
        self.read = planes;
        self.valid = true;
        Ok(())
    }

    /// Bytes held by both buffers.
    pub fn bytes(&self) -> usize {
        self.read
            .iter()
            .chain(&self.write)
            .map(|p| p.data().len() * 4)
            .sum()
    }
}

/// Planes a filter reuses from frame to frame for its temporaries (and, when the caller
/// hands them back with [`super::Filter::recycle`], for its outputs): a fresh multi-MiB
/// buffer costs a page fault per 4 KiB on first touch, which at 1080p is more than some
/// whole stages. Planes taken from here hold stale samples: every user overwrites them.
#[derive(Debug, Default)]
pub struct Scratch {
    free: Vec<Plane<f32>>,
}

/// At most this many planes are kept (enough for every temporary of every filter here).
const SCRATCH_MAX_PLANES: usize = 24;

impl Scratch {
    /// A `width` x `height` plane with unspecified contents.
    pub fn plane(&mut self, width: usize, height: usize) -> Plane<f32> {
        match self.free.iter().position(|p| p.size() == (width, height)) {
            Some(i) => self.free.swap_remove(i),
            None => Plane::new(width, height),
        }
    }

    /// `N` planes with unspecified contents.
    pub fn planes<const N: usize>(&mut self, width: usize, height: usize) -> [Plane<f32>; N] {
        std::array::from_fn(|_| self.plane(width, height))
    }

    /// Every plane held, for a caller that keeps them elsewhere.
    pub fn drain(&mut self) -> Vec<Plane<f32>> {
        std::mem::take(&mut self.free)
    }

    /// Takes planes back for reuse.
    pub fn recycle(&mut self, planes: impl IntoIterator<Item = Plane<f32>>) {
        let start = self.free.len();
        self.free.extend(planes);
        // Debug builds (the tests) poison what comes back, so a stage that reads a reused
        // plane before writing all of it shows NaN instead of passing by luck.
        if cfg!(debug_assertions) {
            for p in &mut self.free[start..] {
                p.data_mut().fill(f32::NAN);
            }
        }
        self.free.truncate(SCRATCH_MAX_PLANES);
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.free.iter().map(|p| p.data().len() * 4).sum()
    }
}
