//! Frame-number file naming as studios write it: a file-name pattern with one frame-number
//! token, for input sequences and for output paths.
//!
//! The token forms and how names match are documented on [`FramePattern`].
//!
//! # Output naming
//!
//! [`OutputNaming`] says where `filter -o` writes each frame: a directory, where every
//! output keeps its input's file name, or a pattern, numbered by frame.
//! [`refuse_overwrite`] checks the planned output files against the inputs and each
//! other before anything is written.

use super::{FileType, IoError};
use std::collections::HashMap;
use std::ffi::OsString;
use std::fmt;
use std::path::{Component, Path, PathBuf};

/// The most digits a width may ask for: `u64::MAX` has 20.
const MAX_WIDTH: usize = 20;

/// The pattern forms, for messages.
const FORMS: &str = "`####` (Nuke), `%04d` (printf), `@@@@` (oiiotool) or `$F4` (Houdini)";

/// The kind of a frame token.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// `%d`, `%0Nd`.
    Printf,
    /// A run of `#`.
    Hash,
    /// A run of `@`.
    At,
    /// `$F`, `$FN`.
    Houdini,
}

/// A token found in a path component: its byte range and width.
#[derive(Clone, Copy, Debug)]
struct Token {
    start: usize,
    end: usize,
    width: usize,
    kind: Kind,
}

/// The frame tokens of one path component, left to right; Err for a width over
/// [`MAX_WIDTH`] (the message names the token).
fn tokens(text: &str) -> Result<Vec<Token>, String> {
    let bytes = text.as_bytes();
    let mut found = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let token = match bytes[i] {
            b'%' => {
                let digits = bytes[i + 1..].iter().take_while(|b| b.is_ascii_digit()).count();
                let d = i + 1 + digits;
                if bytes.get(d) == Some(&b'd') {
                    let width = if digits == 0 {
                        0
                    } else {
                        text[i + 1..d].parse().unwrap_or(usize::MAX)
                    };
                    Some(Token {
                        start: i,
                        end: d + 1,
                        width,
                        kind: Kind::Printf,
                    })
                } else {
                    None
                }
            }
            c @ (b'#' | b'@') => {
                let run = bytes[i..].iter().take_while(|&&b| b == c).count();
                Some(Token {
                    start: i,
                    end: i + run,
                    width: run,
                    kind: if c == b'#' { Kind::Hash } else { Kind::At },
                })
            }
            b'$' if bytes.get(i + 1) == Some(&b'F') => match bytes.get(i + 2) {
                Some(&b) if b.is_ascii_digit() => Some(Token {
                    start: i,
                    end: i + 3,
                    width: usize::from(b - b'0'),
                    kind: Kind::Houdini,
                }),
                Some(&b) if b.is_ascii_alphabetic() || b == b'_' => None,
                _ => Some(Token {
                    start: i,
                    end: i + 2,
                    width: 0,
                    kind: Kind::Houdini,
                }),
            },
            _ => None,
        };
        match token {
            Some(t) => {
                if t.width > MAX_WIDTH {
                    return Err(format!(
                        "frame token `{}` asks for {} digits; a frame number has at most {MAX_WIDTH}",
                        &text[t.start..t.end],
                        if t.width == usize::MAX {
                            "too many".to_string()
                        } else {
                            t.width.to_string()
                        },
                    ));
                }
                found.push(t);
                i = t.end;
            }
            None => i += 1,
        }
    }
    Ok(found)
}

/// A file-name pattern with one frame-number token: `dir/prefix<token>suffix`, such as
/// `renders/shot.####.exr` or `renders/shot_%04d.exr`.
///
/// # Tokens
///
/// | token                  | width     | written by           | frame 7 | frame 12345 |
/// |------------------------|-----------|----------------------|---------|-------------|
/// | `%d`                   | none      | printf, Nuke, ffmpeg | `7`     | `12345`     |
/// | `%04d`                 | 4         | printf, Nuke, ffmpeg | `0007`  | `12345`     |
/// | `####` (N `#`)         | N         | Nuke                 | `0007`  | `12345`     |
/// | `@@@@` (N `@`)         | N         | oiiotool             | `0007`  | `12345`     |
/// | `$F`                   | none      | Houdini              | `7`     | `12345`     |
/// | `$F4` (`$F1`..`$F9`)   | the digit | Houdini              | `0007`  | `12345`     |
///
/// The width is the least number of digits: a number is zero-padded
/// up to it and written in full when it has more digits, as Nuke does (`10000` for
/// `####`). A run of N `#` is N digits, Nuke's convention, so `#` alone is one digit;
/// oiiotool reads a single `#` as four digits, and we do not follow it there (write `####`
/// or `@@@@` for four). `%4d` (no zero) is read as `%04d`: nobody pads file names with
/// spaces. `$F` takes one digit after it (`$F10` is `$F1` then `0`); `$F` followed by a
/// letter or `_` is another Houdini variable (`$FF`, `$FPS`, `$FSTART`) and is kept as
/// text. A `%` that does not start `%d`/`%0Nd` is text. Widths above 20 (the digits of
/// the largest `u64`) are refused.
///
/// # Where the token may be
///
/// Only in the file name, the last path component: all frames live in one directory. A
/// `%d`-style or `$F` token in a directory component is an error; `#` and `@` there are
/// ordinary characters, since real paths have them (`user@host`, `take#2`). A spec ending
/// in a path separator names a directory and has no file name, so no token. Two tokens in
/// the file name (`shot_%04d.####.exr`, or `##@@`, which is two runs) are an error that
/// names both.
///
/// # Matching
///
/// [`FramePattern::matches`] accepts exactly the names [`FramePattern::format`] writes:
/// digits that are the number zero-padded to the width, with more digits only when the
/// number needs them. With `####`, `shot.0007.exr` is frame 7 and `shot.12345.exr` frame
/// 12345, but `shot.7.exr` (too few digits) and `shot.00007.exr` (padding past the width)
/// are not frames of the pattern; with `%d`, `shot.0007.exr` is not either. So reading and
/// writing agree, and a missing frame's expected name is the real one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePattern {
    /// The directory part as written (empty for a bare file name).
    dir: PathBuf,
    /// The file name before the token.
    prefix: String,
    /// The token as written (`####`, `%04d`, ...), for messages.
    token: String,
    /// The file name after the token.
    suffix: String,
    /// The least number of digits (0 and 1 both mean no padding).
    width: usize,
}

impl FramePattern {
    /// Parses `spec`: `Ok(None)` when its file name has no frame token (a plain path,
    /// a directory or a glob), `Ok(Some)` with one token, and
    /// [`IoError::Argument`] for two tokens in the file name, a `%d` or `$F` token in a
    /// directory component, or a width over 20 digits.
    pub fn parse(spec: &str) -> Result<Option<FramePattern>, IoError> {
        let path = Path::new(spec);
        let ends_in_separator = spec.chars().last().is_some_and(std::path::is_separator);
        let name = match path.file_name().and_then(|n| n.to_str()) {
            Some(name) if !ends_in_separator => Some(name),
            _ => None,
        };
        let dir = match name {
            Some(_) => path.parent().unwrap_or(Path::new("")),
            None => path,
        };
        let bad = |reason: String| IoError::Argument(format!("{spec}: {reason}"));
        for component in dir.components() {
            let Component::Normal(part) = component else {
                continue;
            };
            let Some(part) = part.to_str() else { continue };
            let found = tokens(part).map_err(bad)?;
            if let Some(t) = found
                .iter()
                .find(|t| matches!(t.kind, Kind::Printf | Kind::Houdini))
            {
                return Err(bad(format!(
                    "frame token `{}` in the directory `{part}`; only the file name may hold the \
                     frame number (all frames in one directory), e.g. renders/shot.####.exr",
                    &part[t.start..t.end]
                )));
            }
        }
        let Some(name) = name else { return Ok(None) };
        let found = tokens(name).map_err(bad)?;
        match found[..] {
            [] => Ok(None),
            [t] => Ok(Some(FramePattern {
                dir: dir.to_path_buf(),
                prefix: name[..t.start].to_string(),
                token: name[t.start..t.end].to_string(),
                suffix: name[t.end..].to_string(),
                width: t.width,
            })),
            [a, b, ..] => Err(bad(format!(
                "two frame-number tokens in the file name, `{}` and `{}`; a pattern has one \
                 (write {FORMS} once, e.g. shot.####.exr)",
                &name[a.start..a.end],
                &name[b.start..b.end]
            ))),
        }
    }

    /// The number as the token writes it: zero-padded to the width, in full when longer.
    fn digits(&self, number: u64) -> String {
        format!("{number:0w$}", w = self.width)
    }

    /// The file name of frame `number` (no directory).
    pub fn file_name(&self, number: u64) -> String {
        format!("{}{}{}", self.prefix, self.digits(number), self.suffix)
    }

    /// The path of frame `number`: the pattern's directory as written joined with
    /// [`file_name`](Self::file_name) (so a bare pattern gives a bare file name).
    pub fn format(&self, number: u64) -> PathBuf {
        self.dir.join(self.file_name(number))
    }

    /// The frame number of `file_name` (a name, not a path) when it is a frame of this
    /// pattern: prefix, digits, suffix, the digits exactly as [`format`](Self::format)
    /// writes them (at least `width` of them, leading zeros only up to the width).
    pub fn matches(&self, file_name: &str) -> Option<u64> {
        let mid = self.middle(file_name)?;
        let number: u64 = mid.parse().ok()?;
        (self.digits(number) == mid).then_some(number)
    }

    /// Whether `file_name` is prefix, any run of digits, suffix: a frame of this
    /// pattern, or of the same name with another padding (for a hint when nothing
    /// matches).
    pub(super) fn matches_any_padding(&self, file_name: &str) -> bool {
        self.middle(file_name).is_some()
    }

    /// The digits between prefix and suffix, when that is all there is between them.
    fn middle<'a>(&self, file_name: &'a str) -> Option<&'a str> {
        let mid = file_name.strip_prefix(&self.prefix)?.strip_suffix(&self.suffix)?;
        (!mid.is_empty() && mid.bytes().all(|b| b.is_ascii_digit())).then_some(mid)
    }

    /// What the token asks for, in words, for messages: "frame numbers zero-padded to 4
    /// digits (shot.0001.exr)".
    pub(super) fn padding_in_words(&self) -> String {
        let how = if self.width > 1 {
            format!("frame numbers zero-padded to {} digits", self.width)
        } else {
            "frame numbers without zero padding".to_string()
        };
        format!("`{}` means {how} ({})", self.token, self.file_name(1))
    }

    /// The directory the frames are in: as written, or `.` for a bare file name.
    pub fn dir(&self) -> &Path {
        if self.dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            &self.dir
        }
    }

    /// The least number of digits (0 for `%d` and `$F`, N for N `#`).
    pub fn width(&self) -> usize {
        self.width
    }
}

/// The pattern as written (`renders/shot.####.exr`).
impl fmt::Display for FramePattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = format!("{}{}{}", self.prefix, self.token, self.suffix);
        write!(f, "{}", self.dir.join(name).display())
    }
}

/// The file format of a filtered output, from its name's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputFormat {
    /// OpenEXR: the input with its colour replaced (see `io::output`).
    Exr,
    /// 8-bit sRGB PNG of the filtered colour, clamped to [0, 1].
    Png,
    /// 8-bit sRGB JPEG (quality 95) of the filtered colour, clamped to [0, 1].
    Jpeg,
}

impl OutputFormat {
    /// The extensions written, for messages.
    const WRITTEN: &'static str = ".exr, .png, .jpg or .jpeg";

    /// Image formats that are not written, which `-o` refuses rather than take for a
    /// directory's name.
    const IMAGE_EXTENSIONS: [&'static str; 10] = [
        "tif", "tiff", "bmp", "tga", "dpx", "cin", "hdr", "webp", "gif", "sgi",
    ];

    /// The format `path` names: `.exr` (or no extension, or one of digits only, as in
    /// `shot.1001`), `.png`, `.jpg`/`.jpeg` (any case). TIFF and any other extension are
    /// refused with [`IoError::Argument`] saying what is written.
    pub fn of(path: &Path) -> Result<OutputFormat, IoError> {
        let Some(ext) = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()) else {
            return Ok(OutputFormat::Exr);
        };
        match ext.as_str() {
            "exr" => Ok(OutputFormat::Exr),
            "png" => Ok(OutputFormat::Png),
            "jpg" | "jpeg" => Ok(OutputFormat::Jpeg),
            _ if ext.bytes().all(|b| b.is_ascii_digit()) => Ok(OutputFormat::Exr),
            "tif" | "tiff" => Err(IoError::Argument(format!(
                "{}: TIFF output is not built in (the image codecs compiled in are PNG and JPEG);                  write {} and convert",
                path.display(),
                Self::WRITTEN
            ))),
            _ => Err(IoError::Argument(format!(
                "{}: unknown output format .{ext}; the extension picks it: {}",
                path.display(),
                Self::WRITTEN
            ))),
        }
    }
}

/// Where `filter -o` writes frame N of input file P.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OutputNaming {
    /// Into this directory, each output under its input's name with the extension `.exr`
    /// (`in/shot.1001.png` gives `dir/shot.1001.exr`): base name and frame number kept.
    Dir(PathBuf),
    /// Numbered by the pattern: frame N is `pattern.format(N)`.
    Pattern(FramePattern),
    /// One frame, to this file (see [`OutputNaming::parse_for`]).
    File(PathBuf),
}

impl OutputNaming {
    /// Reads an output spec. An existing directory is a directory (even with `#` or `@`
    /// in its name); otherwise a spec with a frame token is a pattern; otherwise it is a
    /// directory (created when written), except that an existing file, or a name ending
    /// in an image extension (`.exr`, `.png`, `.jpg`), is refused with
    /// [`IoError::Argument`]: one file cannot hold a sequence, and the message shows the
    /// pattern forms.
    pub fn parse(spec: &str) -> Result<OutputNaming, IoError> {
        if spec.is_empty() {
            return Err(IoError::Argument(format!(
                "the output is empty; give a directory (frames keep their input names) or a \
                 pattern such as out/shot.####.exr ({FORMS})"
            )));
        }
        let path = Path::new(spec);
        if path.is_dir() {
            return Ok(OutputNaming::Dir(path.to_path_buf()));
        }
        if let Some(pattern) = FramePattern::parse(spec)? {
            OutputFormat::of(&pattern.format(0))?;
            return Ok(OutputNaming::Pattern(pattern));
        }
        let example = || match (path.file_stem(), path.extension()) {
            (Some(stem), Some(ext)) => {
                let mut name = stem.to_os_string();
                name.push(".####.");
                name.push(ext);
                path.with_file_name(name).display().to_string()
            }
            _ => "out/shot.####.exr".to_string(),
        };
        if path.is_file() {
            return Err(IoError::Argument(format!(
                "{spec} is an existing file; the output is a directory (frames keep their input \
                 names) or a pattern with a frame-number token such as {} ({FORMS})",
                example()
            )));
        }
        if FileType::of(path).is_some() {
            return Err(IoError::Argument(format!(
                "{spec}: one file cannot hold a sequence; give a directory (frames keep their \
                 input names) or a pattern with a frame-number token such as {} ({FORMS})",
                example()
            )));
        }
        // An image format's name is no directory name: say it is not written.
        let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
        if ext.is_some_and(|e| OutputFormat::IMAGE_EXTENSIONS.contains(&e.as_str())) {
            OutputFormat::of(path)?;
        }
        Ok(OutputNaming::Dir(path.to_path_buf()))
    }

    /// [`OutputNaming::parse`] for an input of `frames` frames: one frame may also go to one
    /// file named with an image extension (`-o out.exr`, `-o out.png`; an existing file is
    /// replaced).
    pub fn parse_for(spec: &str, frames: usize) -> Result<OutputNaming, IoError> {
        let path = Path::new(spec);
        let names_a_file = !path.is_dir()
            && !spec.ends_with(std::path::is_separator)
            && path.extension().is_some()
            && FramePattern::parse(spec)?.is_none();
        if frames == 1 && names_a_file {
            let ext = path
                .extension()
                .unwrap_or_default()
                .to_string_lossy()
                .to_ascii_lowercase();
            if FileType::of(path).is_some() || ext == "tif" || ext == "tiff" {
                OutputFormat::of(path)?;
                return Ok(OutputNaming::File(path.to_path_buf()));
            }
        }
        Self::parse(spec)
    }

    /// Where frame `number`, read from `input`, is written: for a directory, the input's
    /// file name with the extension `.exr` (`frame_<number>.exr` when the input has no
    /// name); for a pattern, [`FramePattern::format`]`(number)`.
    pub fn path(&self, input: &Path, number: u64) -> PathBuf {
        match self {
            OutputNaming::Dir(dir) => {
                let name = match input.file_stem() {
                    Some(stem) if !stem.is_empty() => {
                        let mut name = stem.to_os_string();
                        name.push(".exr");
                        name
                    }
                    _ => OsString::from(format!("frame_{number:04}.exr")),
                };
                dir.join(name)
            }
            OutputNaming::Pattern(pattern) => pattern.format(number),
            OutputNaming::File(path) => path.clone(),
        }
    }

    /// The PNG preview written beside [`path`](Self::path): the same name with the
    /// extension `.png` in place of an image extension (`shot.1001.exr` gives
    /// `shot.1001.png`), or `.png` added when the name has none (`shot.1001` gives
    /// `shot.1001.png`, not `shot.png`).
    pub fn preview_path(&self, input: &Path, number: u64) -> PathBuf {
        let path = self.path(input, number);
        if FileType::of(&path).is_some() {
            path.with_extension("png")
        } else {
            let mut name = path.into_os_string();
            name.push(".png");
            PathBuf::from(name)
        }
    }

    /// The directory the outputs go to, where `records.json` goes too (`.` for a bare
    /// pattern).
    pub fn dir(&self) -> &Path {
        match self {
            OutputNaming::Dir(dir) => dir,
            OutputNaming::Pattern(pattern) => pattern.dir(),
            OutputNaming::File(path) => match path.parent() {
                Some(dir) if !dir.as_os_str().is_empty() => dir,
                _ => Path::new("."),
            },
        }
    }
}

/// The directory, or the pattern as written.
impl fmt::Display for OutputNaming {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OutputNaming::Dir(dir) => write!(f, "{}", dir.display()),
            OutputNaming::Pattern(pattern) => write!(f, "{pattern}"),
            OutputNaming::File(path) => write!(f, "{}", path.display()),
        }
    }
}

/// The file `path` names, whether or not it exists yet: the canonical path when it
/// exists (symbolic links resolved, so a link to an input is that input), otherwise its
/// deepest existing ancestor made canonical, joined with the rest with `.` and `..`
/// resolved by name (what is not there yet cannot be a link).
fn file_key(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    if let Ok(canonical) = abs.canonicalize() {
        return canonical;
    }
    for ancestor in abs.ancestors().skip(1) {
        if let Ok(mut key) = ancestor.canonicalize() {
            let rest = abs.strip_prefix(ancestor).expect("an ancestor is a prefix");
            for part in rest.components() {
                match part {
                    Component::ParentDir => {
                        key.pop();
                    }
                    Component::Normal(p) => key.push(p),
                    _ => {}
                }
            }
            return key;
        }
    }
    abs
}

/// Refuses a plan of output files that would destroy an input or write one file twice,
/// before anything is written: [`IoError::Argument`] naming the file when an output is an
/// input (compared as files: the same directory after resolving links and `..`, and the
/// same name; the output need not exist yet), or when two outputs are the same file.
pub fn refuse_overwrite(outputs: &[PathBuf], inputs: &[PathBuf]) -> Result<(), IoError> {
    let inputs: HashMap<PathBuf, &PathBuf> = inputs.iter().map(|p| (file_key(p), p)).collect();
    let mut seen: HashMap<PathBuf, &PathBuf> = HashMap::with_capacity(outputs.len());
    for output in outputs {
        let key = file_key(output);
        if let Some(input) = inputs.get(&key) {
            let same = if input.as_os_str() == output.as_os_str() {
                String::new()
            } else {
                format!(" ({} is the same file)", input.display())
            };
            return Err(IoError::Argument(format!(
                "{} is an input frame{same}; writing the output there would overwrite it: choose \
                 another output directory or pattern",
                output.display()
            )));
        }
        if let Some(first) = seen.insert(key, output) {
            let which = if first.as_os_str() == output.as_os_str() {
                format!("{} would be written twice", output.display())
            } else {
                format!("{} and {} are the same file", first.display(), output.display())
            };
            return Err(IoError::Argument(format!(
                "{which}: two outputs would go to one file; give each frame its own name (a \
                 pattern with a frame-number token, {FORMS})"
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(spec: &str) -> FramePattern {
        FramePattern::parse(spec)
            .unwrap_or_else(|e| panic!("{spec}: {e}"))
            .unwrap_or_else(|| panic!("{spec}: no token"))
    }

    fn err(spec: &str) -> String {
        match FramePattern::parse(spec) {
            Err(e) => e.to_string(),
            Ok(p) => panic!("{spec}: parsed as {p:?}"),
        }
    }

    #[test]
    fn printf_tokens() {
        let p = pattern("frame_%04d.exr");
        assert_eq!(p.width(), 4);
        assert_eq!(p.matches("frame_0012.exr"), Some(12));
        assert_eq!(p.matches("frame_12.exr"), None);
        assert_eq!(p.matches("frame_0012.png"), None);
        assert_eq!(p.format(3), PathBuf::from("frame_0003.exr"));
        let p = pattern("f%d.png");
        assert_eq!(p.width(), 0);
        assert_eq!(p.matches("f123.png"), Some(123));
        assert_eq!(p.matches("f0.png"), Some(0));
        assert_eq!(p.format(7), PathBuf::from("f7.png"));
        // `%4d` is read as `%04d`; `%s` and a lone `%` are text.
        assert_eq!(pattern("f%4d.exr").format(7), PathBuf::from("f0007.exr"));
        assert_eq!(FramePattern::parse("frame_%s.exr").unwrap(), None);
        assert_eq!(pattern("100%_%03d.exr").file_name(5), "100%_005.exr");
    }

    #[test]
    fn hash_runs_are_nuke_widths() {
        let p = pattern("renders/shot.####.exr");
        assert_eq!(p.width(), 4);
        assert_eq!(p.dir(), Path::new("renders"));
        assert_eq!(p.format(1001), PathBuf::from("renders/shot.1001.exr"));
        assert_eq!(p.format(7), PathBuf::from("renders/shot.0007.exr"));
        assert_eq!(p.matches("shot.1001.exr"), Some(1001));
        // Nuke, not oiiotool: one `#` is one digit.
        let p = pattern("shot.#.exr");
        assert_eq!(p.width(), 1);
        assert_eq!(p.format(7), PathBuf::from("shot.7.exr"));
        assert_eq!(p.matches("shot.1001.exr"), Some(1001));
        assert_eq!(pattern("s_##.exr").file_name(3), "s_03.exr");
    }

    #[test]
    fn at_runs_are_oiiotool_widths() {
        let p = pattern("shot.@@@.exr");
        assert_eq!(p.width(), 3);
        assert_eq!(p.file_name(42), "shot.042.exr");
        assert_eq!(p.matches("shot.042.exr"), Some(42));
        assert_eq!(pattern("shot.@.exr").file_name(42), "shot.42.exr");
    }

    #[test]
    fn houdini_tokens() {
        let p = pattern("geo/shot.$F.exr");
        assert_eq!(p.width(), 0);
        assert_eq!(p.format(12), PathBuf::from("geo/shot.12.exr"));
        assert_eq!(p.matches("shot.0012.exr"), None);
        let p = pattern("shot.$F4.exr");
        assert_eq!(p.width(), 4);
        assert_eq!(p.file_name(12), "shot.0012.exr");
        for n in 2..=9 {
            assert_eq!(pattern(&format!("s$F{n}")).width(), n);
        }
        // `$F` at the end, and one digit only.
        assert_eq!(pattern("shot_$F").file_name(3), "shot_3");
        assert_eq!(pattern("s$F10.exr").file_name(3), "s30.exr");
        // Other Houdini variables are text.
        assert_eq!(FramePattern::parse("shot.$FF.exr").unwrap(), None);
        assert_eq!(FramePattern::parse("$FPS.exr").unwrap(), None);
    }

    #[test]
    fn numbers_wider_than_the_padding_are_written_and_matched_in_full() {
        let p = pattern("shot.####.exr");
        assert_eq!(p.file_name(12345), "shot.12345.exr");
        assert_eq!(p.matches("shot.12345.exr"), Some(12345));
        // Too few digits, padding past the width, signs and empty digits: not frames.
        for name in [
            "shot.7.exr",
            "shot.00007.exr",
            "shot.+007.exr",
            "shot..exr",
            "shot.0x07.exr",
        ] {
            assert_eq!(p.matches(name), None, "{name}");
        }
        let p = pattern("f%d");
        assert_eq!(p.matches("f18446744073709551615"), Some(u64::MAX));
        assert_eq!(p.matches("f18446744073709551616"), None);
        assert_eq!(pattern("f%020d").file_name(1), "f00000000000000000001");
    }

    #[test]
    fn format_and_matches_are_inverse() {
        for spec in [
            "a%d.exr",
            "a%03d.exr",
            "a#.exr",
            "a####.exr",
            "a@@.exr",
            "a$F.exr",
            "a$F6.exr",
        ] {
            let p = pattern(spec);
            for n in [0, 1, 9, 10, 999, 1001, 123_456_789, u64::MAX] {
                let name = p.file_name(n);
                assert_eq!(p.matches(&name), Some(n), "{spec}: {name}");
            }
        }
    }

    #[test]
    fn no_token_is_no_pattern() {
        for spec in [
            "renders/shot.exr",
            "renders",
            "renders/",
            "shot_*.exr",
            "shot_[0-9].exr",
            "",
            "..",
        ] {
            assert_eq!(FramePattern::parse(spec).unwrap(), None, "{spec}");
        }
        // `#` and `@` in a directory are text; a spec ending in `/` is a directory.
        assert_eq!(FramePattern::parse("take#2/user@host/shot.exr").unwrap(), None);
        assert_eq!(FramePattern::parse("out/####/").unwrap(), None);
        assert_eq!(pattern("take#2/shot.####.exr").dir(), Path::new("take#2"));
    }

    #[test]
    fn two_tokens_are_refused_naming_both() {
        let e = err("shot_%04d.####.exr");
        assert!(e.contains("`%04d`") && e.contains("`####`"), "{e}");
        let e = err("shot.##@@.exr");
        assert!(e.contains("`##`") && e.contains("`@@`"), "{e}");
        let e = err("shot.$F4_%d.exr");
        assert!(e.contains("`$F4`") && e.contains("`%d`"), "{e}");
    }

    #[test]
    fn tokens_only_in_the_file_name() {
        let e = err("renders/v%03d/shot.####.exr");
        assert!(e.contains("`%03d`") && e.contains("directory"), "{e}");
        let e = err("renders/$F4/shot.exr");
        assert!(e.contains("`$F4`"), "{e}");
    }

    #[test]
    fn widths_past_twenty_digits_are_refused() {
        assert!(err("f%021d.exr").contains("21 digits"));
        assert!(err("f%0999999999999999999999999d.exr").contains("too many"));
        assert!(err(&format!("f{}.exr", "#".repeat(21))).contains("at most 20"));
        assert_eq!(pattern(&format!("f{}.exr", "#".repeat(20))).width(), 20);
    }

    #[test]
    fn display_is_the_pattern_as_written() {
        assert_eq!(pattern("out/shot.$F4.exr").to_string(), "out/shot.$F4.exr");
        assert_eq!(pattern("shot.####.exr").dir(), Path::new("."));
        assert_eq!(pattern("shot.####.exr").format(1), PathBuf::from("shot.0001.exr"));
    }

    #[test]
    fn output_dir_keeps_input_base_names() {
        let out = OutputNaming::parse("no/such/out").unwrap();
        assert_eq!(out, OutputNaming::Dir(PathBuf::from("no/such/out")));
        assert_eq!(out.dir(), Path::new("no/such/out"));
        assert_eq!(
            out.path(Path::new("in/shot.1001.exr"), 1001),
            PathBuf::from("no/such/out/shot.1001.exr")
        );
        assert_eq!(
            out.path(Path::new("in/beauty_v2.0007.png"), 7),
            PathBuf::from("no/such/out/beauty_v2.0007.exr")
        );
        assert_eq!(
            out.preview_path(Path::new("in/shot.1001.exr"), 1001),
            PathBuf::from("no/such/out/shot.1001.png")
        );
        assert_eq!(
            out.path(Path::new(""), 3),
            PathBuf::from("no/such/out/frame_0003.exr")
        );
        let tmp = tempfile::tempdir().unwrap();
        let existing = tmp.path().join("take@2");
        std::fs::create_dir(&existing).unwrap();
        let out = OutputNaming::parse(existing.to_str().unwrap()).unwrap();
        assert_eq!(out, OutputNaming::Dir(existing));
    }

    #[test]
    fn output_pattern_numbers_frames() {
        let out = OutputNaming::parse("out/ta.%04d.exr").unwrap();
        assert_eq!(out.dir(), Path::new("out"));
        assert_eq!(
            out.path(Path::new("in/shot.1001.exr"), 1001),
            PathBuf::from("out/ta.1001.exr")
        );
        assert_eq!(
            out.preview_path(Path::new("x"), 1001),
            PathBuf::from("out/ta.1001.png")
        );
        assert_eq!(out.to_string(), "out/ta.%04d.exr");
        let out = OutputNaming::parse("ta.####").unwrap();
        assert_eq!(out.dir(), Path::new("."));
        assert_eq!(out.preview_path(Path::new("x"), 12), PathBuf::from("ta.0012.png"));
    }

    #[test]
    fn output_format_comes_from_the_extension() {
        let out = OutputNaming::parse("out/a.####.png").unwrap();
        let f = |p: &Path| OutputFormat::of(p).unwrap();
        assert_eq!(f(&out.path(Path::new("x"), 3)), OutputFormat::Png);
        assert_eq!(f(Path::new("a.0001.JPG")), OutputFormat::Jpeg);
        assert_eq!(f(Path::new("a.0001")), OutputFormat::Exr);
        assert_eq!(f(Path::new("a.exr")), OutputFormat::Exr);
        for (spec, says) in [
            ("out/a.####.bmp", "unknown output format .bmp"),
            ("out/a.####.tif", "TIFF output is not built in"),
        ] {
            let e = OutputNaming::parse(spec).unwrap_err().to_string();
            assert!(e.contains(says) && e.contains(".exr, .png, .jpg or .jpeg"), "{e}");
        }
        // One frame may go to one file, of a format that is written.
        let one = OutputNaming::parse_for("out/beauty.exr", 1).unwrap();
        assert_eq!(one, OutputNaming::File(PathBuf::from("out/beauty.exr")));
        assert_eq!(
            one.path(Path::new("in/x.0005.exr"), 5),
            PathBuf::from("out/beauty.exr")
        );
        assert_eq!(one.dir(), Path::new("out"));
        assert_eq!(OutputNaming::parse_for("b.png", 1).unwrap().dir(), Path::new("."));
        assert!(OutputNaming::parse_for("out/b.tiff", 1)
            .unwrap_err()
            .to_string()
            .contains("TIFF"));
        let e = OutputNaming::parse_for("out/beauty.exr", 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("one file cannot hold a sequence"), "{e}");
        // An image format that is not written is no directory either.
        for spec in ["out/beauty.tif", "out/beauty.DPX"] {
            let e = OutputNaming::parse_for(spec, 2).unwrap_err().to_string();
            assert!(e.contains(".exr, .png, .jpg or .jpeg"), "{spec}: {e}");
        }
        assert_eq!(
            OutputNaming::parse_for("out/v1.2", 1).unwrap(),
            OutputNaming::Dir(PathBuf::from("out/v1.2"))
        );
    }

    #[test]
    fn output_refuses_a_single_file() {
        for spec in ["out/beauty.exr", "out/beauty.PNG"] {
            let e = OutputNaming::parse(spec).unwrap_err().to_string();
            assert!(e.contains("one file cannot hold a sequence"), "{e}");
            assert!(e.contains("out/beauty.####."), "{e}");
            assert!(
                e.contains("%04d") && e.contains("@@@@") && e.contains("$F4"),
                "{e}"
            );
        }
        let tmp = tempfile::tempdir().unwrap();
        let file = tmp.path().join("records");
        std::fs::write(&file, "").unwrap();
        let e = OutputNaming::parse(file.to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("is an existing file"), "{e}");
        assert!(OutputNaming::parse("").is_err());
        assert!(OutputNaming::parse("a.%d.#.exr")
            .unwrap_err()
            .to_string()
            .contains("two"));
    }

    #[test]
    fn refuse_overwrite_of_inputs_and_twice_written_files() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        std::fs::create_dir(dir.join("in")).unwrap();
        let inputs: Vec<PathBuf> = (1..=2).map(|n| dir.join(format!("in/shot.{n:04}.exr"))).collect();
        for p in &inputs {
            std::fs::write(p, "").unwrap();
        }
        // Outputs elsewhere, not yet written: fine.
        let out = OutputNaming::parse(dir.join("out/ta.####.exr").to_str().unwrap()).unwrap();
        let outputs: Vec<PathBuf> = inputs.iter().zip(1..).map(|(p, n)| out.path(p, n)).collect();
        refuse_overwrite(&outputs, &inputs).unwrap();
        // The input directory as the output directory: each output is its input.
        let out = OutputNaming::parse(dir.join("in").to_str().unwrap()).unwrap();
        let outputs: Vec<PathBuf> = inputs.iter().zip(1..).map(|(p, n)| out.path(p, n)).collect();
        let e = refuse_overwrite(&outputs, &inputs).unwrap_err().to_string();
        assert!(
            e.contains("shot.0001.exr") && e.contains("is an input frame"),
            "{e}"
        );
        // The same file by another spelling, through a directory not yet made.
        let other = dir.join("out/new/../../in/shot.0002.exr");
        let e = refuse_overwrite(std::slice::from_ref(&other), &inputs)
            .unwrap_err()
            .to_string();
        assert!(e.contains("is the same file"), "{e}");
        // Two outputs on one file.
        let twice = vec![dir.join("out/a.exr"), dir.join("out/./a.exr")];
        let e = refuse_overwrite(&twice, &inputs).unwrap_err().to_string();
        assert!(
            e.contains("are the same file") && e.contains("two outputs"),
            "{e}"
        );
        let twice = vec![dir.join("out/a.exr"), dir.join("out/a.exr")];
        let e = refuse_overwrite(&twice, &[]).unwrap_err().to_string();
        assert!(e.contains("would be written twice"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn refuse_overwrite_follows_links() {
        let tmp = tempfile::tempdir().unwrap();
        let real = tmp.path().join("real");
        std::fs::create_dir(&real).unwrap();
        std::fs::write(real.join("f.0001.exr"), "").unwrap();
        std::os::unix::fs::symlink(&real, tmp.path().join("link")).unwrap();
        let inputs = vec![real.join("f.0001.exr")];
        let e = refuse_overwrite(&[tmp.path().join("link/f.0001.exr")], &inputs)
            .unwrap_err()
            .to_string();
        assert!(e.contains("is an input frame"), "{e}");
    }
}
