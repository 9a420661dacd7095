//! What a capture file is: which files in a camera folder are videos, images or camera
//! sidecars, told by content as well as by name, and the order a camera's files play in.
//! The layout check (`pipeline`) and ingest both ask here, so they cannot disagree.

use std::io::Read;
use std::path::{Path, PathBuf};

/// Video file extensions (lower case; names are compared case-insensitively): ISO media
/// (MP4/MOV), Matroska/WebM, AVI, MPEG transport and program streams (AVCHD `.MTS`,
/// broadcast `.ts`, `.mpg`) and MXF (professional cameras). Files with another name are videos too when their content is
/// one of [`Container`]'s formats.
pub const VIDEO_EXTENSIONS: &[&str] = &[
    "mp4", "mov", "m4v", "mkv", "webm", "avi", "mts", "m2ts", "ts", "mpg", "mpeg", "mxf",
];
/// Image extensions (lower case) of an image-sequence camera's frames (FFmpeg decodes them).
pub const IMAGE_EXTENSIONS: &[&str] = &["jpg", "jpeg", "png", "bmp", "tif", "tiff"];
/// Photo extensions (lower case): the images this tool decodes itself (the `image` crate's
/// PNG and JPEG), such as `stills/` for the pose solver and `pipeline metrics`' inputs.
pub const PHOTO_EXTENSIONS: &[&str] = &["jpg", "jpeg", "png"];
/// Camera sidecar files next to recordings, never footage (GoPro thumbnails and low-res
/// proxies).
pub const SIDECAR_EXTENSIONS: &[&str] = &["thm", "lrv"];

/// The lower-case extension of `path` ("" when it has none).
pub fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Whether `path` names a still image (by its extension).
pub fn is_image(path: &Path) -> bool {
    IMAGE_EXTENSIONS.contains(&extension(path).as_str())
}

/// Whether `path` names a photo ([`PHOTO_EXTENSIONS`]).
pub fn is_photo(path: &Path) -> bool {
    PHOTO_EXTENSIONS.contains(&extension(path).as_str())
}

/// Whether `path` names a camera sidecar file (by its extension).
pub fn is_sidecar(path: &Path) -> bool {
    SIDECAR_EXTENSIONS.contains(&extension(path).as_str())
}

/// Whether `path`'s name says video ([`VIDEO_EXTENSIONS`]).
pub fn has_video_name(path: &Path) -> bool {
    VIDEO_EXTENSIONS.contains(&extension(path).as_str())
}

/// A container format recognised by its first bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Container {
    /// ISO base media: MP4, MOV, M4V, 3GP.
    IsoMedia,
    /// Matroska or WebM.
    Matroska,
    /// RIFF AVI.
    Avi,
    /// MPEG transport stream, 188-byte packets (`.ts`) or 192-byte (`.MTS`/`.m2ts`).
    MpegTs,
    /// MPEG program stream (`.mpg`, DVD `.VOB`).
    MpegPs,
    /// Material Exchange Format (`.MXF`, Sony XDCAM, Canon Cinema EOS).
    Mxf,
}

/// The SMPTE universal label that starts an MXF file's header partition pack (after a
/// run-in this does not look for).
const MXF_PARTITION_KEY: [u8; 13] = [
    0x06, 0x0E, 0x2B, 0x34, 0x02, 0x05, 0x01, 0x01, 0x0D, 0x01, 0x02, 0x01, 0x01,
];

/// Bytes [`sniff`] reads: enough for two 192-byte transport packets.
pub const SNIFF_BYTES: usize = 2 * 192;

/// The container that `head` (a file's first bytes, up to [`SNIFF_BYTES`]) starts like.
pub fn sniff(head: &[u8]) -> Option<Container> {
    let n = head.len();
    if n >= 8
        && matches!(
            &head[4..8],
            b"ftyp" | b"moov" | b"mdat" | b"wide" | b"free" | b"skip"
        )
    {
        return Some(Container::IsoMedia);
    }
    if head.starts_with(&[0x1A, 0x45, 0xDF, 0xA3]) {
        return Some(Container::Matroska);
    }
    if n >= 12 && &head[0..4] == b"RIFF" && &head[8..12] == b"AVI " {
        return Some(Container::Avi);
    }
    if head.starts_with(&[0x00, 0x00, 0x01, 0xBA]) {
        return Some(Container::MpegPs);
    }
    if head.starts_with(&MXF_PARTITION_KEY) {
        return Some(Container::Mxf);
    }
    // Transport streams: a 0x47 sync byte starting each of the first two packets.
    let sync_at = |offset: usize, step: usize| {
        offset + step < n && head[offset] == 0x47 && head[offset + step] == 0x47
    };
    if sync_at(0, 188) || sync_at(4, 192) {
        return Some(Container::MpegTs);
    }
    None
}

/// The container of the file at `path` by its content (`None`: not a video this knows).
pub fn sniff_file(path: &Path) -> std::io::Result<Option<Container>> {
    let mut head = Vec::with_capacity(SNIFF_BYTES);
    std::fs::File::open(path)?
        .take(SNIFF_BYTES as u64)
        .read_to_end(&mut head)?;
    Ok(sniff(&head))
}

/// A GoPro chapter name → (recording number, chapter number): `G?CCNNNN.MP4` (HERO5 and
/// later: `GX`, `GH`, …) and the older `GOPRNNNN.MP4` (chapter 0) + `GPCCNNNN.MP4`.
pub fn gopro_chapter(name: &str) -> Option<(u32, u32)> {
    let upper = name.to_ascii_uppercase();
    let stem = upper.strip_suffix(".MP4")?;
    if stem.len() != 8 || !stem.is_ascii() {
        return None;
    }
    if let Some(recording) = stem.strip_prefix("GOPR") {
        return Some((recording.parse().ok()?, 0));
    }
    let b = stem.as_bytes();
    if b[0] != b'G' || !b[1].is_ascii_alphabetic() || !b[2..].iter().all(u8::is_ascii_digit) {
        return None;
    }
    Some((stem[4..8].parse().ok()?, stem[2..4].parse().ok()?))
}

/// A name split into text and numbers, so `img2` sorts before `img10`.
pub fn natural_key(name: &str) -> Vec<(String, u128)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut digits = c.to_string();
            while let Some(d) = chars.next_if(char::is_ascii_digit) {
                digits.push(d);
            }
            key.push((
                std::mem::take(&mut text),
                digits.parse().unwrap_or(u128::MAX),
            ));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("")
        .to_string()
}

/// Sorts a camera's video files into playback order: GoPro chapters by recording, then
/// chapter; other files in natural name order (`clip2` before `clip10`), after the
/// GoPro ones.
pub fn sort_recordings(files: &mut [PathBuf]) {
    files.sort_by_cached_key(|p| {
        let name = file_name(p);
        match gopro_chapter(&name) {
            Some((recording, chapter)) => (0, recording, chapter, Vec::new()),
            None => (1, 0, 0, natural_key(&name)),
        }
    });
}

/// Sorts image-sequence frames into natural name order.
pub fn sort_images(files: &mut [PathBuf]) {
    files.sort_by_cached_key(|p| natural_key(&file_name(p)));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gopro_chapters_of_both_naming_schemes() {
        assert_eq!(gopro_chapter("GX020012.MP4"), Some((12, 2)));
        assert_eq!(gopro_chapter("gh010007.mp4"), Some((7, 1)));
        assert_eq!(gopro_chapter("GOPR0012.MP4"), Some((12, 0)));
        assert_eq!(gopro_chapter("GP010012.MP4"), Some((12, 1)));
        assert_eq!(gopro_chapter("GX0200.MP4"), None);
        assert_eq!(gopro_chapter("GX020012.MOV"), None);
        assert_eq!(gopro_chapter("clip0001.MP4"), None);
        assert_eq!(gopro_chapter("GÖ020012.MP4"), None);
    }

    #[test]
    fn recordings_sort_by_recording_then_chapter_then_name() {
        let mut files: Vec<PathBuf> = [
            "GX020012.MP4",
            "GX010013.MP4",
            "GX010012.MP4",
            "GP010011.MP4",
            "GOPR0011.MP4",
            "clip10.mts",
            "clip2.mts",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        sort_recordings(&mut files);
        let order: Vec<_> = files.iter().map(|p| p.to_str().unwrap()).collect();
        assert_eq!(
            order,
            [
                "GOPR0011.MP4",
                "GP010011.MP4",
                "GX010012.MP4",
                "GX020012.MP4",
                "GX010013.MP4",
                "clip2.mts",
                "clip10.mts"
            ]
        );
    }

    #[test]
    fn containers_are_told_by_content() {
        let mut mp4 = vec![0, 0, 0, 0x18];
        mp4.extend_from_slice(b"ftypmp42");
        assert_eq!(sniff(&mp4), Some(Container::IsoMedia));
        assert_eq!(
            sniff(&[0x1A, 0x45, 0xDF, 0xA3, 1]),
            Some(Container::Matroska)
        );
        assert_eq!(sniff(b"RIFF\0\0\0\0AVI LIST"), Some(Container::Avi));
        assert_eq!(sniff(&[0, 0, 1, 0xBA, 0x44]), Some(Container::MpegPs));
        let mxf = [&MXF_PARTITION_KEY[..], &[0x02, 0x04, 0x00]].concat();
        assert_eq!(sniff(&mxf), Some(Container::Mxf));
        assert_eq!(sniff(&MXF_PARTITION_KEY[..4]), None, "a bare SMPTE prefix");
        let mut ts = vec![0u8; 2 * 188];
        ts[0] = 0x47;
        ts[188] = 0x47;
        assert_eq!(sniff(&ts), Some(Container::MpegTs));
        let mut m2ts = vec![0u8; 2 * 192];
        m2ts[4] = 0x47;
        m2ts[196] = 0x47;
        assert_eq!(sniff(&m2ts), Some(Container::MpegTs));
        // A stray 0x47 ('G') is not a transport stream.
        let mut text = b"GIF89a".to_vec();
        text.resize(400, b'x');
        assert_eq!(sniff(&text), None);
        assert_eq!(sniff(b""), None);
        assert_eq!(sniff(b"hello, world"), None);
        assert_eq!(sniff(b"Good morning"), None);
    }

    #[test]
    fn names_are_case_insensitive() {
        assert!(has_video_name(Path::new("00001.MTS")));
        assert!(has_video_name(Path::new("a.M2TS")));
        assert!(is_image(Path::new("x.TIFF")));
        assert!(is_sidecar(Path::new("GX010001.THM")));
        assert!(!has_video_name(Path::new("notes.txt")));
    }
}
