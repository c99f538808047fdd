//! An RGB picture in memory and its PNG encoding: what the map files ([`picture`](crate::picture))
//! and the evaluation's figures (`sonar-eval`) draw on.
//!
//! Pixel (0, 0) is the top-left corner. Drawing outside the picture is clipped, so callers can
//! draw marks that reach over an edge.

use std::io::Write;

use crate::map::MapError;

/// An RGB picture, 8 bits per channel, rows top to bottom.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Canvas {
    width: usize,
    height: usize,
    rgb: Vec<u8>,
}

impl Canvas {
    /// A `width` × `height` picture in one colour.
    pub fn new(width: usize, height: usize, fill: [u8; 3]) -> Self {
        Self {
            width,
            height,
            rgb: fill.repeat(width * height),
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The pixels, row by row from the top, three bytes (R, G, B) each.
    pub fn rgb(&self) -> &[u8] {
        &self.rgb
    }

    /// The colour at (`x`, `y`).
    ///
    /// # Panics
    ///
    /// If the pixel is outside the picture.
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside a {} × {} picture",
            self.width,
            self.height
        );
        let i = 3 * (y * self.width + x);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Paints pixel (`x`, `y`); nothing outside the picture.
    pub fn set(&mut self, x: usize, y: usize, rgb: [u8; 3]) {
        if x < self.width && y < self.height {
            let i = 3 * (y * self.width + x);
            self.rgb[i..i + 3].copy_from_slice(&rgb);
        }
    }

    /// Paints the `w` × `h` rectangle whose top-left pixel is (`x`, `y`), clipped to the picture.
    pub fn fill(&mut self, x: usize, y: usize, w: usize, h: usize, rgb: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.set(xx, yy, rgb);
            }
        }
    }

    /// Copies `other` with its top-left corner at (`x`, `y`), clipped to the picture.
    pub fn blit(&mut self, other: &Canvas, x: usize, y: usize) {
        for yy in 0..other.height {
            for xx in 0..other.width {
                self.set(x + xx, y + yy, other.pixel(xx, yy));
            }
        }
    }

    /// Encodes the picture as an 8-bit RGB PNG at `compression`, with `comment` as a `Comment`
    /// text chunk if given.
    pub fn write_png<W: Write>(
        &self,
        out: W,
        compression: png::Compression,
        comment: Option<&str>,
    ) -> Result<(), MapError> {
        let too_large = || MapError::PictureSize {
            width: self.width,
            height: self.height,
        };
        let width = u32::try_from(self.width).map_err(|_| too_large())?;
        let height = u32::try_from(self.height).map_err(|_| too_large())?;
        let mut encoder = png::Encoder::new(out, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(compression);
        if let Some(comment) = comment {
            encoder.add_text_chunk("Comment".to_owned(), comment.to_owned())?;
        }
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&self.rgb)?;
        writer.finish()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: [u8; 3] = [255, 0, 0];
    const BLUE: [u8; 3] = [0, 0, 255];
    const WHITE: [u8; 3] = [255, 255, 255];

    #[test]
    fn drawing_is_clipped_to_the_picture() {
        let mut c = Canvas::new(4, 3, WHITE);
        c.set(4, 0, RED);
        c.set(0, 3, RED);
        c.fill(2, 1, 5, 5, RED);
        assert_eq!(c.pixel(1, 1), WHITE);
        assert_eq!(c.pixel(2, 1), RED);
        assert_eq!(c.pixel(3, 2), RED);
        let mut big = Canvas::new(6, 5, BLUE);
        big.blit(&c, 3, 3);
        assert_eq!(big.pixel(2, 3), BLUE);
        assert_eq!(big.pixel(3, 3), WHITE);
        assert_eq!(big.pixel(5, 4), RED);
        assert_eq!((big.width(), big.height(), big.rgb().len()), (6, 5, 90));
    }

    #[test]
    fn pngs_decode_to_the_same_pixels_and_comment() {
        let mut c = Canvas::new(5, 2, WHITE);
        c.set(4, 1, RED);
        for (compression, comment) in [
            (png::Compression::Fast, Some("a comment")),
            (png::Compression::High, None),
        ] {
            let mut bytes = Vec::new();
            c.write_png(&mut bytes, compression, comment).unwrap();
            let mut reader = png::Decoder::new(std::io::Cursor::new(&bytes[..]))
                .read_info()
                .unwrap();
            let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
            let info = reader.next_frame(&mut pixels).unwrap();
            assert_eq!((info.width, info.height), (5, 2));
            assert_eq!(&pixels[..info.buffer_size()], c.rgb());
            let texts: Vec<_> = reader
                .info()
                .uncompressed_latin1_text
                .iter()
                .map(|t| (t.keyword.as_str(), t.text.as_str()))
                .collect();
            let expected: Vec<_> = comment.map(|t| ("Comment", t)).into_iter().collect();
            assert_eq!(texts, expected);
        }
    }
}
