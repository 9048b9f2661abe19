#include "sql_connection.h"

#include <cstdio>
#include <string>

namespace lf::server {

std::string sql_text(const SqlValue& value) {
    if (std::holds_alternative<std::nullptr_t>(value)) return "";
    if (const bool* b = std::get_if<bool>(&value)) return *b ? "true" : "false";
    if (const int64_t* i = std::get_if<int64_t>(&value)) return std::to_string(*i);
    if (const double* d = std::get_if<double>(&value)) {
        char buf[32];
        std::snprintf(buf, sizeof buf, "%.17g", *d);
        return buf;
    }
    return std::get<std::string>(value);
}

std::string SqlResult::text(size_t row, int column) const { return sql_text(rows.at(row).at(size_t(column))); }

int64_t SqlResult::integer(size_t row, int column) const {
    const SqlValue& value = rows.at(row).at(size_t(column));
    if (const int64_t* i = std::get_if<int64_t>(&value)) return *i;
    if (const double* d = std::get_if<double>(&value)) return int64_t(*d);
    if (const bool* b = std::get_if<bool>(&value)) return *b ? 1 : 0;
    if (const std::string* s = std::get_if<std::string>(&value)) return std::stoll(*s);
    return 0;
}

double SqlResult::real(size_t row, int column) const {
    const SqlValue& value = rows.at(row).at(size_t(column));
    if (const double* d = std::get_if<double>(&value)) return *d;
    if (const int64_t* i = std::get_if<int64_t>(&value)) return double(*i);
    if (const bool* b = std::get_if<bool>(&value)) return *b ? 1 : 0;
    if (const std::string* s = std::get_if<std::string>(&value)) return std::stod(*s);
    return 0;
}

}  // namespace lf::server
