//! How an export writes its cells: the separator between them and the decimal mark
//! inside them. Spreadsheets and tracker software in a locale whose decimal mark is the
//! comma write `;`-separated files with `0,365`; both are detected from the text or
//! named, and anything that reads two ways is refused with the line and column.

use crate::data::recording::{file_err, DataError, Table};

/// The separator and decimal mark of an export.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dialect {
    /// The byte between cells: `,`, `;` or a tab.
    pub delimiter: u8,
    /// Whether numbers use the decimal comma (`0,365`).
    pub decimal_comma: bool,
}

impl Dialect {
    /// Comma-separated with decimal points.
    pub const PLAIN: Dialect = Dialect {
        delimiter: b',',
        decimal_comma: false,
    };
}

/// The name of a delimiter in messages.
pub fn delimiter_name(delimiter: u8) -> &'static str {
    match delimiter {
        b',' => "','",
        b';' => "';'",
        b'\t' => "a tab",
        _ => "another byte",
    }
}

/// The delimiter of `text`: `given`, or the one of `,`, `;` and tab that its header line
/// holds. A header with more than one of them is refused (the export must name it).
pub fn detect_delimiter(text: &str, file: &str, given: Option<u8>) -> Result<u8, DataError> {
    if let Some(d) = given {
        return Ok(d);
    }
    let header = text.lines().next().unwrap_or("");
    let found: Vec<u8> = [b',', b';', b'\t']
        .into_iter()
        .filter(|&d| header.as_bytes().contains(&d))
        .collect();
    match found.as_slice() {
        [] => Ok(b','),
        [one] => Ok(*one),
        several => Err(DataError::Line {
            file: file.to_string(),
            line: 1,
            message: format!(
                "the header line holds {}: name the separator (comma, semicolon or tab)",
                several
                    .iter()
                    .map(|&d| delimiter_name(d))
                    .collect::<Vec<_>>()
                    .join(" and ")
            ),
        }),
    }
}

/// Whether the cells of `columns` use the decimal comma: `given`, or what they show. A
/// comma-separated file has decimal points; otherwise a number written with a comma and
/// none with a point means the comma, and both in one file is refused, naming one cell
/// of each.
pub(in crate::data) fn detect_decimal_comma(
    table: &Table,
    delimiter: u8,
    columns: &[usize],
    given: Option<bool>,
) -> Result<bool, DataError> {
    if let Some(comma) = given {
        return Ok(comma);
    }
    if delimiter == b',' {
        return Ok(false);
    }
    let (mut point, mut comma) = (None, None);
    for (line, cells) in &table.rows {
        for &c in columns {
            let cell = &cells[c];
            if point.is_none() && cell.contains('.') {
                point = Some((*line, c));
            }
            if comma.is_none() && cell.contains(',') {
                comma = Some((*line, c));
            }
        }
        if point.is_some() && comma.is_some() {
            break;
        }
    }
    match (point, comma) {
        (Some((pl, pc)), Some((cl, cc))) => Err(file_err(
            table.file,
            format!(
                "numbers with a decimal point (line {pl}, column {:?}) and with a decimal comma \
                 (line {cl}, column {:?}): name the decimal mark (point or comma)",
                table.header[pc], table.header[cc]
            ),
        )),
        (None, Some(_)) => Ok(true),
        _ => Ok(false),
    }
}

/// The cell at `line`, column `c` as a finite number in `dialect` (`None` when empty).
/// With the decimal comma, a point (a thousands separator?) or a second comma is refused.
pub(in crate::data) fn number(
    table: &Table,
    dialect: Dialect,
    line: u64,
    c: usize,
    cell: &str,
) -> Result<Option<f64>, DataError> {
    if !dialect.decimal_comma {
        return table.number(line, c, cell);
    }
    if cell.contains('.') {
        return Err(table.at(
            line,
            c,
            format!(
                "{cell:?} has a decimal point in a file whose decimal mark is the comma (a thousands separator?)"
            ),
        ));
    }
    if cell.matches(',').count() > 1 {
        return Err(table.at(line, c, format!("{cell:?} has more than one decimal comma")));
    }
    table.number(line, c, &cell.replace(',', "."))
}
