//! Frame sequences: a directory, a frame-number pattern (`shot.####.exr`, `frame_%04d.exr`,
//! `shot.@@@@.exr`, `shot.$F4.exr`: see [`FramePattern`]), a glob or a single file, sorted
//! by frame number.
//!
//! A spec is read as the first of these that applies:
//!
//! 1. an existing directory: every `.exr` in it, or else every PNG/JPEG;
//! 2. an existing file: that one frame (even when its name has `#`, `@`, `%d` or `[`);
//! 3. a file name with a frame-number token: a pattern, its frames the files of its
//!    directory whose names it matches (exactly as it would write them, see
//!    [`FramePattern`]). So `#` is a frame token, never a glob character, and
//!    `shot[v2].####.exr` is a pattern whose `[v2]` is text;
//! 4. a spec with `*`, `?` or `[`: a glob, numbered by the last run of digits in each
//!    file name;
//! 5. anything else: "no such file".
//!
//! A spec with a bad token (two of them, one in a directory) is an error even when a
//! glob could have read it.

use super::{
    frame_and_input, read_raw_in, FileType, FramePattern, InputImage, IoError, ReadOptions, Storage,
};
use crate::frame::Frame;
use std::path::{Path, PathBuf};

/// One file of a sequence.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SequenceEntry {
    /// Frame number (the last run of digits in the file name; the position for a single
    /// file without one).
    pub number: u64,
    /// The file, or for a held frame ([`Missing::Hold`]) the name the missing file would
    /// have (outputs are named after it).
    pub path: PathBuf,
    /// A held frame: the file read in place of the missing `path` (the nearest frame
    /// before it, else after it); its motion is read as zero, since nothing moved.
    pub held_from: Option<PathBuf>,
    /// The first frame after frames left out by [`Missing::Skip`]: read as a reset, since
    /// its motion points at a frame that is not there.
    pub after_gap: bool,
}

impl SequenceEntry {
    fn new(number: u64, path: PathBuf) -> Self {
        SequenceEntry {
            number,
            path,
            held_from: None,
            after_gap: false,
        }
    }

    /// The file to read: the entry's own, or the held one.
    pub fn source(&self) -> &Path {
        self.held_from.as_deref().unwrap_or(&self.path)
    }
}

/// What to do about frame numbers missing from a sequence (`--missing`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Missing {
    /// Refuse the sequence, naming the first missing frame and the file it should be.
    #[default]
    Error,
    /// Leave the missing numbers out; the frame after a gap starts history afresh.
    Skip,
    /// Repeat the nearest frame before (else after) under the missing number, motion zero.
    Hold,
}

impl std::str::FromStr for Missing {
    type Err = IoError;
    fn from_str(s: &str) -> Result<Self, IoError> {
        match s {
            "error" => Ok(Missing::Error),
            "skip" => Ok(Missing::Skip),
            "hold" => Ok(Missing::Hold),
            _ => Err(IoError::Argument(format!(
                "--missing {s:?}: expected skip, error or hold"
            ))),
        }
    }
}

/// Most missing frames [`Missing::Hold`] fills in (a typo in `--frames` is not a million
/// copies of one file).
const MAX_HELD: u64 = 100_000;

/// Frame numbers `first..=last` every `step` (`--frames 3-10`, `1001-1100:2`, `7`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    /// The first number.
    pub first: u64,
    /// The last number (included when the step reaches it).
    pub last: u64,
    /// The step, at least 1.
    pub step: u64,
}

impl FrameRange {
    /// Whether `number` is one of the range's.
    pub fn contains(&self, number: u64) -> bool {
        (self.first..=self.last).contains(&number) && (number - self.first).is_multiple_of(self.step)
    }

    /// The numbers, in order.
    pub fn numbers(&self) -> impl Iterator<Item = u64> {
        (self.first..=self.last).step_by(usize::try_from(self.step).unwrap_or(usize::MAX))
    }
}

impl std::str::FromStr for FrameRange {
    type Err = IoError;
    fn from_str(s: &str) -> Result<Self, IoError> {
        let bad = |why: &str| {
            IoError::Argument(format!(
                "--frames {s:?}: {why}; expected FIRST-LAST or FIRST-LAST:STEP (3-10, 1001-1100:2) or one frame"
            ))
        };
        let (span, step) = match s.split_once(':') {
            Some((span, step)) => (span, step.trim().parse::<u64>().map_err(|_| bad("bad step"))?),
            None => (s, 1),
        };
        let num = |t: &str| t.trim().parse::<u64>().map_err(|_| bad("not a frame number"));
        let (first, last) = match span.split_once('-') {
            Some((a, b)) => (num(a)?, num(b)?),
            None => (num(span)?, num(span)?),
        };
        if step == 0 {
            return Err(bad("the step is 0"));
        }
        if last < first {
            return Err(bad("the last frame is before the first"));
        }
        Ok(FrameRange { first, last, step })
    }
}

/// Which frames of a sequence to read (`--frames`, `--missing`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Selection {
    /// The frame numbers wanted (None: every one from the first file's to the last's).
    pub range: Option<FrameRange>,
    /// What to do about wanted numbers without a file.
    pub missing: Missing,
}

/// `path` with the last run of digits in its file stem replaced by `number`, zero-padded
/// to the run's width: the name a missing frame of a numbered file's sequence has.
fn renumbered(path: &Path, number: u64) -> PathBuf {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    let stem_len = path.file_stem().and_then(|n| n.to_str()).map_or(0, str::len);
    let Some(end) = name[..stem_len]
        .rfind(|c: char| c.is_ascii_digit())
        .map(|i| i + 1)
    else {
        return path.to_path_buf();
    };
    let start = name[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    let digits = format!("{number:0w$}", w = end - start);
    path.with_file_name(format!("{}{digits}{}", &name[..start], &name[end..]))
}

/// An ordered list of frame files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sequence {
    /// What the user wrote.
    pub spec: String,
    /// The files, by frame number.
    pub entries: Vec<SequenceEntry>,
}

/// A file's frame number: the last run of ASCII digits in its stem (`shot.1001.exr` is
/// 1001). The one numbering rule for files: a frame read from a file takes this as its
/// index (in a sequence, in `info`); a file without one keeps the index it declares
/// (`afterimage.index`, else 0).
pub fn frame_number(path: &Path) -> Option<u64> {
    let stem = path.file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = stem[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    stem[start..end].parse().ok()
}

impl Sequence {
    /// Opens a sequence from a directory (every `.exr`, or else every PNG/JPEG, in it), a
    /// single file, a frame-number pattern (`shot.####.exr`, `frame_%04d.exr`,
    /// `shot.@@@@.exr`, `shot.$F4.exr`) or a glob (`*`, `?`, `[`), in that order of
    /// precedence (see the module). Frames are sorted by number; a number missing between
    /// the first and the last is an error that names it (for a pattern, with the file
    /// name it should have).
    pub fn open(spec: &str) -> Result<Sequence, IoError> {
        Self::open_selected(spec, &Selection::default())
    }

    /// [`Sequence::open`] of the frames `selection` picks, missing ones handled as it says.
    pub fn open_selected(spec: &str, selection: &Selection) -> Result<Sequence, IoError> {
        let path = Path::new(spec);
        let entries: Vec<SequenceEntry>;
        let mut pattern = None;
        if path.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| IoError::os(path, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file() && FileType::of(p).is_some())
                .collect();
            if files.iter().any(|p| FileType::of(p) == Some(FileType::Exr)) {
                files.retain(|p| FileType::of(p) == Some(FileType::Exr));
            }
            if files.is_empty() {
                return Err(IoError::Sequence(format!(
                    "{spec}: directory has no .exr, .png or .jpg files"
                )));
            }
            entries = Self::number(spec, files)?;
        } else if path.is_file() {
            entries = vec![SequenceEntry::new(
                frame_number(path).unwrap_or(0),
                path.to_path_buf(),
            )];
        } else if let Some(p) = FramePattern::parse(spec)? {
            entries = Self::matching(spec, &p)?;
            pattern = Some(p);
        } else if spec.contains(['*', '?', '[']) {
            let files: Vec<PathBuf> = glob::glob(spec)
                .map_err(|e| IoError::Sequence(format!("{spec}: bad glob pattern: {e}")))?
                .filter_map(Result::ok)
                .filter(|p| p.is_file())
                .collect();
            if files.is_empty() {
                return Err(IoError::Sequence(format!("{spec}: no file matches the glob")));
            }
            entries = Self::number(spec, files)?;
        } else {
            return Err(IoError::os(
                path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or directory"),
            ));
        }
        Self::ordered(spec, entries, pattern.as_ref(), selection)
    }

    /// `entries` sorted by number, checked for repeated numbers, those `selection` picks,
    /// and missing ones handled as it says (a missing one named with the file `pattern`
    /// would give it).
    fn ordered(
        spec: &str,
        mut entries: Vec<SequenceEntry>,
        pattern: Option<&FramePattern>,
        selection: &Selection,
    ) -> Result<Sequence, IoError> {
        entries.sort_by_key(|e| e.number);
        for pair in entries.windows(2) {
            let (a, b) = (&pair[0], &pair[1]);
            if a.number == b.number {
                return Err(IoError::Sequence(format!(
                    "{spec}: frame {} appears twice: {} and {}",
                    a.number,
                    a.path.display(),
                    b.path.display()
                )));
            }
        }
        let (all_first, all_last) = (entries[0].number, entries[entries.len() - 1].number);
        if let Some(r) = &selection.range {
            entries.retain(|e| r.contains(e.number));
            if entries.is_empty() {
                return Err(IoError::Sequence(format!(
                    "{spec}: no frame in --frames {}-{}:{} (the files are frames {all_first}-{all_last})",
                    r.first, r.last, r.step
                )));
            }
        }
        let range = selection.range.unwrap_or(FrameRange {
            first: all_first,
            last: all_last,
            step: 1,
        });
        // The name a missing frame's file would have.
        let name_of = |number: u64, near: &SequenceEntry| match pattern {
            Some(p) => p.format(number),
            None => renumbered(&near.path, number),
        };
        let mut out: Vec<SequenceEntry> = Vec::with_capacity(entries.len());
        let mut files = entries.into_iter().peekable();
        let mut gap = false;
        let mut held = 0u64;
        let mut wanted = range.numbers().peekable();
        while let Some(n) = wanted.next() {
            if let Some(e) = files.next_if(|e| e.number == n) {
                out.push(SequenceEntry { after_gap: gap, ..e });
                gap = false;
                continue;
            }
            let before = out.iter().rev().find(|e| e.held_from.is_none()).cloned();
            let after = files.peek().cloned();
            let near = before.clone().or(after.clone()).expect("a file is in the range");
            match selection.missing {
                Missing::Error => {
                    let place = match (before, after) {
                        (Some(a), Some(b)) => {
                            format!("between {} and {}", a.path.display(), b.path.display())
                        }
                        (Some(a), None) => format!("after {}", a.path.display()),
                        (None, Some(b)) => format!("before {}", b.path.display()),
                        (None, None) => unreachable!("a file is in the range"),
                    };
                    return Err(IoError::Sequence(format!(
                        "{spec}: frame {n} is missing (expected {}, {place}); --missing skip or hold goes on without it",
                        name_of(n, &near).display()
                    )));
                }
                Missing::Skip => {
                    gap = !out.is_empty();
                    // Straight to the next file's number, or done.
                    match files.peek().map(|e| e.number) {
                        Some(next) => while wanted.next_if(|&m| m < next).is_some() {},
                        None => break,
                    }
                }
                Missing::Hold => {
                    held += 1;
                    if held > MAX_HELD {
                        return Err(IoError::Sequence(format!(
                            "{spec}: more than {MAX_HELD} missing frames to hold; give --frames the range the files cover ({all_first}-{all_last})"
                        )));
                    }
                    out.push(SequenceEntry {
                        number: n,
                        path: name_of(n, &near),
                        held_from: Some(near.source().to_path_buf()),
                        after_gap: false,
                    });
                }
            }
        }
        let missing: Vec<u64> = out
            .iter()
            .filter(|e| e.held_from.is_some())
            .map(|e| e.number)
            .collect();
        if !missing.is_empty() {
            tracing::warn!("{spec}: {} missing frames held ({missing:?})", missing.len());
        }
        if let Some(e) = out.iter().find(|e| e.after_gap) {
            tracing::warn!(
                "{spec}: missing frames left out (--missing skip); history restarts after each gap, first at frame {}",
                e.number
            );
        }
        Ok(Sequence {
            spec: spec.to_string(),
            entries: out,
        })
    }

    /// The files of `pattern`'s directory that it matches; none is an error, with a hint
    /// when files of the same name have another padding.
    fn matching(spec: &str, pattern: &FramePattern) -> Result<Vec<SequenceEntry>, IoError> {
        let dir = pattern.dir();
        let files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| IoError::os(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect();
        Self::matching_files(spec, pattern, &files)
    }

    /// The `files` (of `pattern`'s directory) that `pattern` matches (see [`Self::matching`]).
    fn matching_files(
        spec: &str,
        pattern: &FramePattern,
        files: &[PathBuf],
    ) -> Result<Vec<SequenceEntry>, IoError> {
        let dir = pattern.dir();
        let mut entries = Vec::new();
        let mut other_padding = None;
        for name in files.iter().filter_map(|p| p.file_name()?.to_str()) {
            match pattern.matches(name) {
                Some(number) => entries.push(SequenceEntry::new(number, pattern.format(number))),
                None if other_padding.is_none() && pattern.matches_any_padding(name) => {
                    other_padding = Some(name.to_string());
                }
                None => {}
            }
        }
        if entries.is_empty() {
            let hint = match other_padding {
                Some(name) => format!(
                    " ({}, but {} has another padding: write the token for it)",
                    pattern.padding_in_words(),
                    dir.join(name).display()
                ),
                None => String::new(),
            };
            return Err(IoError::Sequence(format!(
                "{spec}: no file matches the pattern{hint}"
            )));
        }
        Ok(entries)
    }

    /// Opens a sequence in `storage`: as [`Sequence::open`] for local files; in an object
    /// store, a frame-number pattern (`s3://bucket/shot/beauty.####.exr`), one object
    /// (`.../beauty.0001.exr`), or else a "directory" (`s3://bucket/shot/`: every `.exr`
    /// directly in it). Globs are local only.
    pub fn open_in(spec: &str, storage: &dyn Storage) -> Result<Sequence, IoError> {
        Self::open_in_selected(spec, storage, &Selection::default())
    }

    /// [`Sequence::open_in`] of the frames `selection` picks (see [`Sequence::open_selected`]).
    pub fn open_in_selected(
        spec: &str,
        storage: &dyn Storage,
        selection: &Selection,
    ) -> Result<Sequence, IoError> {
        if storage.is_local() {
            return Self::open_selected(spec, selection);
        }
        let path = Path::new(spec);
        let (entries, pattern) = if let Some(p) = FramePattern::parse(spec)? {
            let files = storage.list(p.dir())?;
            (Self::matching_files(spec, &p, &files)?, Some(p))
        } else if FileType::of(path).is_some() && !spec.ends_with('/') {
            let dir = path.parent().unwrap_or(Path::new(""));
            if !storage.list(dir)?.iter().any(|f| f == path) {
                return Err(IoError::os(
                    path,
                    std::io::Error::new(std::io::ErrorKind::NotFound, "no such object"),
                ));
            }
            let number = frame_number(path).unwrap_or(0);
            (vec![SequenceEntry::new(number, path.to_path_buf())], None)
        } else {
            let files: Vec<PathBuf> = storage
                .list(path)?
                .into_iter()
                .filter(|p| FileType::of(p) == Some(FileType::Exr))
                .collect();
            if files.is_empty() {
                return Err(IoError::Sequence(format!("{spec}: no .exr objects there")));
            }
            (Self::number(spec, files)?, None)
        };
        Self::ordered(spec, entries, pattern.as_ref(), selection)
    }

    fn number(spec: &str, files: Vec<PathBuf>) -> Result<Vec<SequenceEntry>, IoError> {
        if files.len() == 1 {
            let path = files.into_iter().next().expect("one file");
            return Ok(vec![SequenceEntry::new(frame_number(&path).unwrap_or(0), path)]);
        }
        files
            .into_iter()
            .map(|path| match frame_number(&path) {
                Some(number) => Ok(SequenceEntry::new(number, path)),
                None => Err(IoError::Sequence(format!(
                    "{spec}: {} has no frame number in its name",
                    path.display()
                ))),
            })
            .collect()
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the sequence is empty (never, once opened).
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Reads the frames in order, each converted with its predecessor's jitter; in a
    /// sequence the frame index is the file's frame number.
    pub fn frames<'a>(&'a self, opts: &'a ReadOptions) -> impl Iterator<Item = Result<Frame, IoError>> + 'a {
        self.inputs(opts).map(|r| r.map(|(f, _)| f))
    }

    /// [`Sequence::frames`], each with its file kept as the input a filtered result
    /// replaces (see [`super::write_filtered`]).
    pub fn inputs<'a>(
        &'a self,
        opts: &'a ReadOptions,
    ) -> impl Iterator<Item = Result<(Frame, InputImage), IoError>> + 'a {
        self.inputs_jittered(opts, |_| None)
    }

    /// [`Sequence::inputs`] with each frame's jitter from `jitter` (by frame number) where
    /// it gives one, over what the file says; motion is converted with it.
    pub fn inputs_jittered<'a>(
        &'a self,
        opts: &'a ReadOptions,
        jitter: impl Fn(u64) -> Option<[f32; 2]> + 'a,
    ) -> impl Iterator<Item = Result<(Frame, InputImage), IoError>> + 'a {
        self.inputs_in(&super::LocalFiles, opts, jitter, 0)
    }

    /// [`Sequence::inputs_jittered`] from `storage`, starting at position `start`: the frames
    /// are those a read from the first would give (motion converted with the jitter of the
    /// frame before `start`, which is read for it), so a run can resume mid-sequence.
    pub fn inputs_in<'a>(
        &'a self,
        storage: &'a dyn Storage,
        opts: &'a ReadOptions,
        jitter: impl Fn(u64) -> Option<[f32; 2]> + 'a,
        start: usize,
    ) -> impl Iterator<Item = Result<(Frame, InputImage), IoError>> + 'a {
        let mut jitter_prev: Option<Result<[f32; 2], IoError>> = start
            .checked_sub(1)
            .and_then(|k| self.entries.get(k))
            .map(|e| match jitter(e.number) {
                Some(j) => Ok(j),
                None => read_raw_in(storage, e.source()).map(|raw| raw.meta.jitter),
            });
        self.entries.iter().skip(start).map(move |e| {
            let prev = jitter_prev.take().transpose()?;
            let mut raw = read_raw_in(storage, e.source())?;
            if let Some(j) = jitter(e.number) {
                raw.meta.jitter = j;
            }
            let (mut f, input) = frame_and_input(raw, opts, prev)?;
            jitter_prev = Some(Ok(f.meta.jitter));
            if frame_number(&e.path).is_some() {
                f.meta.index = e.number;
            }
            if e.held_from.is_some() {
                // The same picture again: nothing moved.
                if let Some(m) = f.motion_mut() {
                    m.iter_mut().for_each(|p| p.data_mut().fill(0.0));
                }
                if let Some(m) = f.motion_next_mut() {
                    m.iter_mut().for_each(|p| p.data_mut().fill(0.0));
                }
            }
            if e.after_gap {
                f.meta.reset = true;
            }
            Ok((f, input))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Read from a later position, frames are what a read from the first gives: motion of
    /// a jittered convention converted with the real previous frame's jitter (read for it),
    /// or the one `jitter` gives.
    #[test]
    fn a_read_from_mid_sequence_gives_the_frames_a_whole_read_gives() {
        use crate::frame::MotionConvention;
        let dir = tempfile::tempdir().unwrap();
        let mut rng = crate::rng::SplitMix64::new(9);
        for k in 0..4u64 {
            let mut f = crate::filters::check::random_frame(&mut rng, 7, 5, 1.0, 2.0, k);
            f.meta.jitter = [0.1 * k as f32 - 0.2, 0.3 - 0.15 * k as f32];
            let path = dir.path().join(format!("f.{k:04}.exr"));
            super::super::write_exr(&path, &f, &super::super::WriteOptions::default()).unwrap();
        }
        let seq = Sequence::open(&dir.path().display().to_string()).unwrap();
        let opts = ReadOptions {
            motion_convention: Some(MotionConvention {
                jittered: true,
                ..MotionConvention::INTERNAL
            }),
            ..ReadOptions::default()
        };
        let motion = |f: &Frame| -> Vec<u32> {
            f.motion()
                .unwrap()
                .iter()
                .flat_map(|p| p.data().iter().map(|v| v.to_bits()))
                .collect()
        };
        let given = |n: u64| (n == 1).then_some([0.5, -0.5]);
        for jitter in [&(|_| None) as &dyn Fn(u64) -> Option<[f32; 2]>, &given] {
            let read = |start| -> Vec<Vec<u32>> {
                seq.inputs_in(&super::super::LocalFiles, &opts, jitter, start)
                    .map(|r| motion(&r.unwrap().0))
                    .collect()
            };
            let whole = read(0);
            assert_ne!(whole[1], whole[2], "the jitter changes the motion");
            assert_eq!(read(2), whole[2..]);
            assert_eq!(read(1), whole[1..]);
        }
    }

    #[test]
    fn frame_numbers_come_from_the_last_digit_run() {
        assert_eq!(frame_number(Path::new("shot2/frame_0042.exr")), Some(42));
        assert_eq!(frame_number(Path::new("v2_render.0007.exr")), Some(7));
        assert_eq!(frame_number(Path::new("beauty.exr")), None);
    }

    /// Empty files named `names` in a new temporary directory.
    fn files(names: &[&str]) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        for name in names {
            std::fs::write(dir.path().join(name), "").unwrap();
        }
        dir
    }

    fn numbers(seq: &Sequence) -> Vec<u64> {
        seq.entries.iter().map(|e| e.number).collect()
    }

    #[test]
    fn every_token_form_opens_a_sequence() {
        let dir = files(&[
            "shot.1002.exr",
            "shot.1001.exr",
            "shot.1003.exr",
            "shot.1001.png",
            "other.1001.exr",
        ]);
        let d = dir.path().display();
        for token in ["####", "%04d", "%d", "@@@@", "$F4", "$F", "#"] {
            let spec = format!("{d}/shot.{token}.exr");
            let seq = Sequence::open(&spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
            assert_eq!(numbers(&seq), [1001, 1002, 1003], "{spec}");
            assert_eq!(seq.entries[0].path, dir.path().join("shot.1001.exr"), "{spec}");
        }
        // Sequence::open only lists names: these empty files are never read.
        assert_eq!(Sequence::open(&format!("{d}/shot.##.exr")).unwrap().len(), 3);
    }

    #[test]
    fn a_pattern_names_the_missing_frame_file() {
        let dir = files(&["shot.0009.exr", "shot.0010.exr", "shot.0012.exr"]);
        let spec = format!("{}/shot.####.exr", dir.path().display());
        let err = Sequence::open(&spec).unwrap_err().to_string();
        assert!(err.contains("frame 11 is missing"), "{err}");
        assert!(err.contains("shot.0011.exr"), "{err}");
    }

    #[test]
    fn a_pattern_with_the_wrong_padding_says_so() {
        let dir = files(&["shot.1.exr", "shot.2.exr"]);
        let spec = format!("{}/shot.####.exr", dir.path().display());
        let err = Sequence::open(&spec).unwrap_err().to_string();
        assert!(err.contains("no file matches the pattern"), "{err}");
        assert!(
            err.contains("zero-padded to 4 digits") && err.contains("shot.0001.exr"),
            "{err}"
        );
        assert!(err.contains("another padding"), "{err}");
        let spec = format!("{}/shot.#.exr", dir.path().display());
        assert_eq!(numbers(&Sequence::open(&spec).unwrap()), [1, 2]);
    }

    #[test]
    fn numbers_past_the_padding_continue_the_sequence() {
        let dir = files(&["f.9998.exr", "f.9999.exr", "f.10000.exr", "f.010000.exr"]);
        let seq = Sequence::open(&format!("{}/f.####.exr", dir.path().display())).unwrap();
        assert_eq!(numbers(&seq), [9998, 9999, 10000]);
    }

    #[test]
    fn precedence_of_files_patterns_and_globs() {
        // An existing file is itself, whatever characters its name has.
        let dir = files(&[
            "render@2x.png",
            "shot[v2].0001.exr",
            "shot[v2].0002.exr",
            "a1.exr",
            "a2.exr",
        ]);
        let d = dir.path().display();
        let seq = Sequence::open(&format!("{d}/render@2x.png")).unwrap();
        assert_eq!(seq.entries[0].path, dir.path().join("render@2x.png"));
        // A token makes a pattern, its `[v2]` text rather than a glob class.
        let seq = Sequence::open(&format!("{d}/shot[v2].####.exr")).unwrap();
        assert_eq!(numbers(&seq), [1, 2]);
        // Without a token, `[` is a glob.
        let seq = Sequence::open(&format!("{d}/a[12].exr")).unwrap();
        assert_eq!(numbers(&seq), [1, 2]);
        // A bad token is an error, not a glob.
        let err = Sequence::open(&format!("{d}/a%d_#*.exr"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("two frame-number tokens"), "{err}");
    }

    fn selected(spec: &str, range: &str, missing: &str) -> Result<Sequence, IoError> {
        let selection = Selection {
            range: (!range.is_empty()).then(|| range.parse().unwrap()),
            missing: missing.parse().unwrap(),
        };
        Sequence::open_selected(spec, &selection)
    }

    #[test]
    fn frame_ranges_parse_and_bad_ones_say_what_is_expected() {
        let r: FrameRange = "3-10:2".parse().unwrap();
        assert_eq!(r.numbers().collect::<Vec<_>>(), [3, 5, 7, 9]);
        assert!(r.contains(9) && !r.contains(10) && !r.contains(1));
        assert_eq!(
            "7".parse::<FrameRange>().unwrap().numbers().collect::<Vec<_>>(),
            [7]
        );
        for bad in ["10-3", "a-b", "1-5:0", "1-5:x", ""] {
            let e = bad.parse::<FrameRange>().unwrap_err().to_string();
            assert!(
                e.contains(&format!("--frames {bad:?}")) && e.contains("FIRST-LAST"),
                "{e}"
            );
        }
        assert!("later"
            .parse::<Missing>()
            .unwrap_err()
            .to_string()
            .contains("skip, error or hold"));
    }

    /// `--frames` picks numbers; a gap is an error by default, left out (the frame after it
    /// a reset) with skip, or filled with the nearest earlier file under its own name with
    /// hold.
    #[test]
    fn frames_and_missing_select_and_fill_gaps() {
        let dir = files(&[
            "s.0001.exr",
            "s.0002.exr",
            "s.0004.exr",
            "s.0005.exr",
            "s.0006.exr",
        ]);
        let d = dir.path().display();
        let spec = format!("{d}/s.####.exr");
        assert_eq!(numbers(&selected(&spec, "4-6", "error").unwrap()), [4, 5, 6]);
        assert_eq!(numbers(&selected(&spec, "4-6:2", "error").unwrap()), [4, 6]);
        assert_eq!(numbers(&selected(&spec, "1-6:2", "skip").unwrap()), [1, 5]);
        let e = selected(&spec, "2-5", "error").unwrap_err().to_string();
        assert!(
            e.contains("frame 3 is missing") && e.contains("s.0003.exr") && e.contains("--missing"),
            "{e}"
        );
        let e = selected(&spec, "20-30", "error").unwrap_err().to_string();
        assert!(
            e.contains("no frame in --frames 20-30:1 (the files are frames 1-6)"),
            "{e}"
        );
        let skip = selected(&spec, "", "skip").unwrap();
        assert_eq!(numbers(&skip), [1, 2, 4, 5, 6]);
        let gaps: Vec<bool> = skip.entries.iter().map(|e| e.after_gap).collect();
        assert_eq!(gaps, [false, false, true, false, false]);
        // Past the last file with skip: nothing more, whatever the range.
        assert_eq!(
            numbers(&selected(&spec, "5-18446744073709551615", "skip").unwrap()),
            [5, 6]
        );
        let hold = selected(&spec, "2-7", "hold").unwrap();
        assert_eq!(numbers(&hold), [2, 3, 4, 5, 6, 7]);
        let held: Vec<Option<PathBuf>> = hold.entries.iter().map(|e| e.held_from.clone()).collect();
        let file = |n: u64| Some(dir.path().join(format!("s.{n:04}.exr")));
        assert_eq!(held, [None, file(2), None, None, None, file(6)]);
        assert_eq!(hold.entries[1].path, dir.path().join("s.0003.exr"));
        assert_eq!(hold.entries[1].source(), dir.path().join("s.0002.exr"));
        // A directory (no pattern) names a held frame after its neighbour's digits.
        let hold = selected(&d.to_string(), "", "hold").unwrap();
        assert_eq!(hold.entries[2].path, dir.path().join("s.0003.exr"));
        assert_eq!(
            renumbered(Path::new("a/v2_x.0099.exr"), 100),
            Path::new("a/v2_x.0100.exr")
        );
    }
}
