//! Frame sequences: a directory, a printf pattern (`frame_%04d.exr`) or a glob, sorted by
//! frame number.

use super::{read_frame_after, FileType, IoError, ReadOptions};
use crate::frame::Frame;
use std::path::{Path, PathBuf};

/// One file of a sequence.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SequenceEntry {
    /// Frame number (the last run of digits in the file name; the position for a single
    /// file without one).
    pub number: u64,
    /// The file.
    pub path: PathBuf,
}

/// An ordered list of frame files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sequence {
    /// What the user wrote.
    pub spec: String,
    /// The files, by frame number.
    pub entries: Vec<SequenceEntry>,
}

/// The last run of ASCII digits in the file stem, as a number.
fn frame_number(path: &Path) -> Option<u64> {
    let stem = path.file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = stem[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    stem[start..end].parse().ok()
}

/// A printf pattern split at its `%d` / `%0Nd`.
struct Printf<'a> {
    prefix: &'a str,
    suffix: &'a str,
    width: usize,
}

impl<'a> Printf<'a> {
    fn parse(name: &'a str) -> Option<Printf<'a>> {
        let pct = name.find('%')?;
        let rest = &name[pct + 1..];
        let d = rest.find('d')?;
        let spec = &rest[..d];
        if !spec.chars().all(|c| c.is_ascii_digit()) {
            return None;
        }
        Some(Printf {
            prefix: &name[..pct],
            suffix: &rest[d + 1..],
            width: spec.parse().unwrap_or(0),
        })
    }

    fn matches(&self, file: &str) -> Option<u64> {
        let mid = file.strip_prefix(self.prefix)?.strip_suffix(self.suffix)?;
        if mid.is_empty() || !mid.chars().all(|c| c.is_ascii_digit()) || mid.len() < self.width {
            return None;
        }
        mid.parse().ok()
    }

    fn format(&self, n: u64) -> String {
        format!("{}{:0w$}{}", self.prefix, n, self.suffix, w = self.width)
    }
}

impl Sequence {
    /// Opens a sequence from a directory (every `.exr`, or else every PNG/JPEG, in it), a
    /// printf pattern, a glob (`*`, `?`, `[`), or a single file. Frames are sorted by
    /// number; a number missing between the first and the last is an error that names it.
    pub fn open(spec: &str) -> Result<Sequence, IoError> {
        let path = Path::new(spec);
        let mut entries: Vec<SequenceEntry>;
        let mut printf = None;
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
        } else if let Some(p) = path.file_name().and_then(|n| n.to_str()).and_then(Printf::parse) {
            let dir = match path.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => PathBuf::from("."),
            };
            entries = std::fs::read_dir(&dir)
                .map_err(|e| IoError::os(&dir, e))?
                .filter_map(|e| e.ok())
                .filter_map(|e| {
                    let name = e.file_name().to_str()?.to_string();
                    p.matches(&name).map(|number| SequenceEntry {
                        number,
                        path: dir.join(&name),
                    })
                })
                .collect();
            if entries.is_empty() {
                return Err(IoError::Sequence(format!("{spec}: no file matches the pattern")));
            }
            printf = Some((dir, p));
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
        } else if path.is_file() {
            entries = vec![SequenceEntry {
                number: frame_number(path).unwrap_or(0),
                path: path.to_path_buf(),
            }];
        } else {
            return Err(IoError::os(
                path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or directory"),
            ));
        }
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
            if b.number != a.number + 1 {
                let missing = a.number + 1;
                let expected = match &printf {
                    Some((dir, p)) => dir.join(p.format(missing)).display().to_string(),
                    None => format!("a file numbered {missing}"),
                };
                return Err(IoError::Sequence(format!(
                    "{spec}: frame {missing} is missing (expected {expected}, between {} and {})",
                    a.path.display(),
                    b.path.display()
                )));
            }
        }
        Ok(Sequence {
            spec: spec.to_string(),
            entries,
        })
    }

    fn number(spec: &str, files: Vec<PathBuf>) -> Result<Vec<SequenceEntry>, IoError> {
        if files.len() == 1 {
            let path = files.into_iter().next().expect("one file");
            return Ok(vec![SequenceEntry {
                number: frame_number(&path).unwrap_or(0),
                path,
            }]);
        }
        files
            .into_iter()
            .map(|path| match frame_number(&path) {
                Some(number) => Ok(SequenceEntry { number, path }),
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
        let mut jitter_prev = None;
        self.entries.iter().map(move |e| {
            let mut f = read_frame_after(&e.path, opts, jitter_prev)?;
            jitter_prev = Some(f.meta.jitter);
            f.meta.index = e.number;
            Ok(f)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_numbers_come_from_the_last_digit_run() {
        assert_eq!(frame_number(Path::new("shot2/frame_0042.exr")), Some(42));
        assert_eq!(frame_number(Path::new("v2_render.0007.exr")), Some(7));
        assert_eq!(frame_number(Path::new("beauty.exr")), None);
    }

    #[test]
    fn printf_patterns() {
        let p = Printf::parse("frame_%04d.exr").unwrap();
        assert_eq!(p.matches("frame_0012.exr"), Some(12));
        assert_eq!(p.matches("frame_12.exr"), None);
        assert_eq!(p.matches("frame_0012.png"), None);
        assert_eq!(p.format(3), "frame_0003.exr");
        let p = Printf::parse("f%d.png").unwrap();
        assert_eq!(p.matches("f123.png"), Some(123));
        assert!(Printf::parse("frame_%s.exr").is_none());
    }
}
