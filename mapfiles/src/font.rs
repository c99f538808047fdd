//! A 5-pixel-high font with just the characters the legend of a picture needs (digits, units,
//! "unknown"), so that labels need no font file. Characters without a glyph draw as blanks.

/// Glyph height in font pixels; glyphs are 3 pixels wide, `m` and `w` 5, with 1 pixel between.
pub const GLYPH_H: u32 = 5;

/// Width and rows top-down, bit `width - 1` = left column.
fn glyph(c: char) -> (u32, [u8; 5]) {
    let narrow = |rows| (3, rows);
    match c {
        '0' => narrow([0b111, 0b101, 0b101, 0b101, 0b111]),
        '1' => narrow([0b010, 0b110, 0b010, 0b010, 0b111]),
        '2' => narrow([0b111, 0b001, 0b111, 0b100, 0b111]),
        '3' => narrow([0b111, 0b001, 0b111, 0b001, 0b111]),
        '4' => narrow([0b101, 0b101, 0b111, 0b001, 0b001]),
        '5' => narrow([0b111, 0b100, 0b111, 0b001, 0b111]),
        '6' => narrow([0b111, 0b100, 0b111, 0b101, 0b111]),
        '7' => narrow([0b111, 0b001, 0b001, 0b001, 0b001]),
        '8' => narrow([0b111, 0b101, 0b111, 0b101, 0b111]),
        '9' => narrow([0b111, 0b101, 0b111, 0b001, 0b111]),
        '.' => narrow([0b000, 0b000, 0b000, 0b000, 0b010]),
        'c' => narrow([0b000, 0b111, 0b100, 0b100, 0b111]),
        'k' => narrow([0b100, 0b101, 0b110, 0b101, 0b101]),
        'n' => narrow([0b000, 0b110, 0b101, 0b101, 0b101]),
        'o' => narrow([0b000, 0b111, 0b101, 0b101, 0b111]),
        'u' => narrow([0b000, 0b101, 0b101, 0b101, 0b111]),
        'm' => (5, [0b00000, 0b11110, 0b10101, 0b10101, 0b10101]),
        'w' => (5, [0b00000, 0b10001, 0b10101, 0b10101, 0b01010]),
        _ => narrow([0; 5]),
    }
}

/// Width in image pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: u32) -> u32 {
    let advance: u32 = text.chars().map(|c| glyph(c).0 + 1).sum();
    advance.saturating_sub(1) * scale
}

/// Calls `set(x, y)` for every image pixel of `text` drawn with its top-left corner at (`x0`, `y0`),
/// each font pixel a `scale × scale` square.
pub fn draw(text: &str, x0: u32, y0: u32, scale: u32, mut set: impl FnMut(u32, u32)) {
    let mut gx = x0;
    for c in text.chars() {
        let (width, rows) = glyph(c);
        for (row, bits) in rows.into_iter().enumerate() {
            for col in 0..width {
                if bits & (1 << (width - 1 - col)) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        set(gx + col * scale + dx, y0 + row as u32 * scale + dy);
                    }
                }
            }
        }
        gx += (width + 1) * scale;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_glyph_by_glyph_at_scale() {
        let mut px = Vec::new();
        draw("1.", 10, 20, 2, |x, y| px.push((x, y)));
        // '1' has 8 font pixels, '.' one; each is 2 × 2.
        assert_eq!(px.len(), (8 + 1) * 4);
        assert!(px.contains(&(12, 20)), "top of the 1");
        assert!(
            px.contains(&(10 + 8 + 2, 20 + 8)),
            "the dot, one advance further"
        );
        assert_eq!(text_width("1.", 2), 14);
        assert_eq!(text_width("2 m", 2), (4 + 4 + 5) * 2);
        assert_eq!(text_width("", 2), 0);
        // A wide glyph moves the next one further.
        let mut m1 = Vec::new();
        draw("m1", 0, 0, 1, |x, y| m1.push((x, y)));
        assert!(m1.contains(&(4, 2)), "right leg of the m");
        assert!(m1.contains(&(6 + 1, 0)), "top of the 1 after the m");
    }
}
